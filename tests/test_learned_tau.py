"""Learned time constants τs, τr: kernels against their closed forms, gradients against finite
differences of the SLAYER-linearised network on the batch path and the event-driven engine,
and τ carried by checkpoints, the streaming engine and NIR."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from test_train_loop import dataset as tiny_dataset  # noqa: F401  (a fixture)

from spikegyro.models.registry import load_checkpoint, save_checkpoint
from spikegyro.models.snn6 import SNN6, adapt_state
from spikegyro.snn.functional import fire, psp, surrogate_gradient
from spikegyro.snn.kernels import (
    TAU_MAX_MS,
    TAU_MIN_MS,
    param_from_tau,
    refractory_kernel,
    refractory_kernel_of,
    srm_kernel,
    srm_kernel_of,
    tau_from_param,
)
from spikegyro.snn.layers import GASP, SRMConv, SRMDense, SRMParams
from spikegyro.snn.sparse import EventDrivenStack
from spikegyro.train.loss import angular_velocity_loss

CUT = 0.05
SPEC = {"representation": "spikes", "sensor": [80, 64], "scale": 1.0, "window_ms": 40}


def _window(shape: tuple[int, ...], density: float, seed: int = 1) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return (torch.rand(shape, generator=generator) < density).double()


# --------------------------------------------------------------------------- kernels of τ


@pytest.mark.parametrize("tau", [0.6, 1.0, 2.0, 3.7, 8.0, 25.0])
def test_kernels_of_tau_are_the_fixed_kernels_with_their_closed_form_derivative(tau):
    tau_t = torch.tensor(tau, dtype=torch.float64, requires_grad=True)
    eps = srm_kernel_of(tau_t)
    torch.testing.assert_close(eps.detach(), srm_kernel(tau, dtype=torch.float64))
    (grad,) = torch.autograd.grad(eps.sum(), tau_t)
    k = np.arange(eps.numel())
    closed = k / tau * np.exp(1 - k / tau) * (k - tau) / tau**2  # ∂ε[k]/∂τs
    assert float(grad) == pytest.approx(closed.sum(), rel=1e-12)
    nu = refractory_kernel_of(0.3, tau_t)
    torch.testing.assert_close(nu.detach(), refractory_kernel(0.3, tau, dtype=torch.float64))
    (grad,) = torch.autograd.grad(nu.sum(), tau_t)
    j = np.arange(nu.numel() - 1)
    assert float(grad) == pytest.approx((-0.6 * np.exp(-j / tau) * j / tau**2).sum(), rel=1e-12)


def test_parametrisation_is_bounded_monotonic_and_inverts():
    params = torch.linspace(-0.5, 0.5, 1001, dtype=torch.float64)  # σ(±10): near the bounds
    taus = tau_from_param(params)
    assert float(taus.min()) >= TAU_MIN_MS and float(taus.max()) <= TAU_MAX_MS
    assert bool((taus.diff() > 0).all())
    assert float(tau_from_param(torch.tensor(1e3))) <= TAU_MAX_MS
    for tau in (0.7, 2.0, 8.0, 30.0):
        assert float(tau_from_param(torch.tensor(param_from_tau(tau)))) == pytest.approx(tau)
    with pytest.raises(ValueError, match="must lie in"):
        param_from_tau(TAU_MAX_MS)
    # kernel lengths at the bounds stay sane
    assert srm_kernel(TAU_MIN_MS).numel() == 4 and srm_kernel(TAU_MAX_MS).numel() == 245
    assert refractory_kernel(0.4, TAU_MAX_MS).numel() == 142


def test_psp_kernel_gradient_over_several_blocks_matches_finite_differences():
    """A window longer than two PSP blocks (T = 400, L = 150): ∂/∂τs of Σ g·psp(x, ε(τs))."""
    x = torch.randn(400, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    g = torch.randn(400, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    tau = torch.tensor(19.5, dtype=torch.float64, requires_grad=True)
    kernel = srm_kernel_of(tau)
    assert kernel.numel() > 128
    (analytic,) = torch.autograd.grad((psp(x, kernel, dim=0) * g).sum(), tau)
    taps = np.arange(kernel.numel())

    def loss(value: float) -> float:  # a direct convolution at the same length
        eps = torch.from_numpy(taps / value * np.exp(1 - taps / value))
        out = sum(eps[k] * F.pad(x, (0, 0, k, 0))[: x.shape[0]] for k in range(eps.numel()))
        return float((out * g).sum())

    h = 1e-5
    assert float(analytic) == pytest.approx((loss(19.5 + h) - loss(19.5 - h)) / (2 * h), rel=1e-7)


# -------------------------------------------------- gradients against finite differences


def _tiny(learn: bool = True) -> tuple[list[SRMConv], SRMDense]:
    """Two learned-τ conv layers and a readout in float64, at time constants of no special
    value (neither the defaults nor whole milliseconds)."""
    torch.manual_seed(4)
    convs = [
        SRMConv(2, 4, SRMParams(2.0, 0.3, 1.0, 0.2, rho_cut=CUT), 3, 2, learn_tau=learn),
        SRMConv(4, 5, SRMParams(4.0, 0.25, 4.0, 0.5, rho_cut=CUT), 3, 1, 0, True, learn),
    ]
    fc = SRMDense(5, 3, SRMParams(8.0), learn_tau=learn)
    for layer, taus in zip((*convs, fc), ((2.3, 1.4), (3.1, 2.6), (5.5, None)), strict=True):
        layer.double()
        layer.reset_parameters(2.5)
        layer.set_time_constants(*taus)
    return convs, fc


def _direct_psp(z: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Σ_k kernel[k]·z[..., t − k], time last, as an explicit sum over delays."""
    steps = z.shape[-1]
    return sum(kernel[k] * F.pad(z, (k, 0))[..., :steps] for k in range(kernel.numel()))


def _conv(conv: SRMConv, spikes: torch.Tensor) -> torch.Tensor:
    """conv(s) at every step, (N, C, H, W, T) → (N, C_out, H', W', T)."""
    n, c, h, w, t = spikes.shape
    frames = spikes.permute(0, 4, 1, 2, 3).reshape(n * t, c, h, w)
    z = F.conv2d(frames, conv.weight, stride=conv.stride)
    return z.reshape(n, t, *z.shape[1:]).permute(0, 2, 3, 4, 1)


def _kernels_at(layer, params: dict[str, float], name: str) -> list[torch.Tensor]:
    """[ε(τs), ν(τr)] (ν of a spiking layer only) in closed form at τ = tau_from_param(ρ) of
    the parameters ``params[name.tau_*_param]``, at the lengths of the layer's current kernels."""
    keys = [f"{name}.tau_{k}_param" for k in ("sr" if layer.params.spiking else "s")]
    taus = [tau_from_param(torch.tensor(params[k], dtype=torch.float64)) for k in keys]
    k = torch.arange(layer.srm_kernel.numel(), dtype=torch.float64)
    kernels = [k / taus[0] * torch.exp(1 - k / taus[0])]
    if layer.params.spiking:
        j = torch.arange(layer.ref_kernel.numel() - 1, dtype=torch.float64)
        nu = -layer.params.scale_ref * layer.params.theta * torch.exp(-j / taus[1])
        kernels.append(torch.cat([nu.new_zeros(1), nu]))
    return kernels


@torch.no_grad()
def _linearised_loss(convs, fc, params: dict[str, float], x, y, start) -> float:
    """The loss of the network whose spikes are s0 + ρ(u0)·(u(τ) − u0), with u(τ) = ε(τs) * z +
    ν(τr) * s0 (the spikes in the refractory term held fixed) and τ = tau_from_param(ρ) of the
    parameters ``params`` (by name): its exact derivative is SLAYER's gradient wrt τ (ρ at the
    forward potentials, none through the refractory feedback)."""
    spikes, spikes0 = x, x
    for i, conv in enumerate(convs):
        v0 = _direct_psp(_conv(conv, spikes0), conv.srm_kernel)
        fired, u0 = fire(v0, conv.params.theta, conv.ref_kernel)
        p = conv.params
        rho = surrogate_gradient(u0.clone(), p.theta, p.scale_rho, p.tau_rho, p.rho_cut)
        eps, nu = _kernels_at(conv, params, f"conv{i + 1}")
        u = _direct_psp(_conv(conv, spikes), eps) + _direct_psp(fired, nu)
        spikes, spikes0 = fired + rho * (u - u0), fired
    current = F.linear(spikes.mean(dim=(2, 3)).transpose(1, 2), fc.weight).transpose(1, 2)
    out = _direct_psp(current, _kernels_at(fc, params, "fc")[0])
    return float(angular_velocity_loss(out, y, start))


@pytest.mark.parametrize("engine", ["dense", "sparse"])
def test_tau_gradients_match_finite_differences_of_the_linearised_network(engine):
    convs, fc = _tiny()
    x = _window((2, 2, 11, 11, 24), 0.3)
    y = torch.randn(2, 3, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    if engine == "sparse":
        stack = EventDrivenStack(convs, GASP(), threads=1)
        pooled = stack.pooled(x)
    else:
        pooled = GASP()(convs[1](convs[0](x)))
        stack = None
    loss = angular_velocity_loss(fc(pooled), y, 4)
    loss.backward()
    layers = {"conv1": convs[0], "conv2": convs[1], "fc": fc}
    params = {f"{n}.{k}": p for n, layer in layers.items() for k, p in layer.named_parameters()
              if k.startswith("tau_")}  # fmt: skip
    base = {k: float(p.detach()) for k, p in params.items()}
    assert _linearised_loss(convs, fc, base, x, y, 4) == pytest.approx(
        float(loss.detach()), rel=1e-12
    )
    if stack is not None:
        assert min(stack.timing.active) > 0
    h = 1e-6
    for name, p in params.items():
        shifted = [
            _linearised_loss(convs, fc, {**base, name: base[name] + s * h}, x, y, 4)
            for s in (1, -1)
        ]
        numeric = (shifted[0] - shifted[1]) / (2 * h)
        assert float(p.grad) != 0.0, name
        assert float(p.grad) == pytest.approx(numeric, rel=1e-6, abs=1e-9), name


def test_engine_and_batch_path_give_snn6_the_same_tau_gradients_in_float64():
    torch.manual_seed(0)
    model = SNN6(learn_tau=True).double()
    for i, conv in enumerate(model.convs):  # longer and shorter than the paper's
        conv.set_time_constants(conv.params.tau_s * (1.6 if i % 2 else 0.7), 1.3 + i)
    model.set_surrogate_cut(CUT)
    model.freeze(1)  # layer 1's τ stays: the engine's backward stops above it
    x = _window((2, 2, 64, 80, 30), 0.05)
    y = torch.randn(2, 3, 30, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    grads = []
    for threads in (None, 2):
        model.use_event_engine(threads)
        model.zero_grad(set_to_none=True)
        angular_velocity_loss(model(x), y, 10).backward()
        grads.append({n: p.grad for n, p in model.named_parameters() if p.grad is not None})
    dense, sparse = grads
    assert set(dense) == set(sparse)
    assert "conv1.tau_s_param" not in dense and "conv5.tau_r_param" in dense
    for name, grad in dense.items():
        assert float(grad.norm()) > 0, name
        torch.testing.assert_close(sparse[name], grad, rtol=1e-9, atol=1e-12, msg=name)


# ------------------------------------------------------------ checkpoints, stream, NIR


def _learned_snn6(seed: int = 0) -> SNN6:
    """An SNN-6 with learned τ moved from the paper's values, so its kernels change length."""
    torch.manual_seed(seed)
    model = SNN6(learn_tau=True)
    for conv in model.convs:
        conv.set_time_constants(conv.params.tau_s * 2.5, conv.params.tau_r * 1.5)
    model.fc.set_time_constants(11.0)
    return model.eval()


def test_checkpoint_round_trip_keeps_learned_tau_and_kernels(tmp_path):
    model = _learned_snn6()
    optimizer = torch.optim.SGD(model.tau_parameters(), lr=0.01)
    for p in model.tau_parameters():
        p.grad = torch.ones_like(p)
    optimizer.step()  # τ moved after the last forward: saving must follow it
    path = save_checkpoint(tmp_path / "lt.pt", model, name="snn6",
                           model_kwargs={"learn_tau": True}, input_spec=SPEC)  # fmt: skip
    loaded, _ = load_checkpoint(path)
    assert loaded.learn_tau and loaded.time_constants() == model.time_constants()
    assert loaded.conv3.srm_kernel.numel() == srm_kernel(model.conv3.current_params().tau_s).numel()
    assert loaded.conv3.srm_kernel.numel() > srm_kernel(4.0).numel()
    x = _window((1, 2, 64, 80, 40), 0.05).float()
    with torch.no_grad():
        expected, spikes = model.forward_with_spikes(x)
        got = loaded(x)
    assert spikes[-1].sum() > 0
    assert torch.equal(got, expected)


def test_fixed_and_learned_checkpoints_start_each_other(tmp_path):
    fixed = SNN6().eval()
    learned = SNN6(learn_tau=True).eval()
    learned.load_state_dict(adapt_state(fixed.state_dict(), learned))  # as train --init does
    x = _window((1, 2, 64, 80, 40), 0.05).float()
    with torch.no_grad():  # the taps agree to float32 rounding (τ from a float32 parameter)
        torch.testing.assert_close(learned(x), fixed(x), rtol=1e-5, atol=1e-6)
    for name, taus in fixed.time_constants().items():
        for key, value in taus.items():
            assert learned.time_constants()[name][key] == pytest.approx(value, rel=1e-6)
    source = _learned_snn6()
    plain = SNN6().eval()
    plain.load_state_dict(adapt_state(source.state_dict(), plain))
    assert not any("tau" in k for k in plain.state_dict())
    assert plain.time_constants() == SNN6().time_constants()


def test_streaming_engine_runs_learned_tau_as_the_batch_forward():
    from stream_helpers import exact_double, random_events, step_offsets

    from spikegyro.events.representations import spike_tensor
    from spikegyro.stream.model import spec_from_model
    from spikegyro.stream.stateful import StreamingSNN

    height, width, steps = 64, 72, 100
    model = exact_double(_learned_snn6(1))
    events = random_events(width, height, steps, rate=0.01, seed=6)
    x = spike_tensor(events.x, events.y, events.t, events.p, height=height, width=width,
                     t_start_us=0, num_bins=steps)  # fmt: skip
    with torch.no_grad():
        out, spikes = model.forward_with_spikes(torch.from_numpy(x)[None].double())
    spec = spec_from_model(model, (2, height, width), np.float64)
    assert spec.layers[2].srm_kernel.size == model.conv3.srm_kernel.numel() > 40
    engine = StreamingSNN(spec, np.float64)
    got = engine.run(*step_offsets(events, 0, steps))
    assert engine.spike_counts.tolist() == [int(s.sum()) for s in spikes]
    assert engine.spike_counts[-1] > 0
    expected = out[0].T.numpy()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_nir_carries_learned_tau(tmp_path):
    pytest.importorskip("nir")
    from spikegyro.models.nir import export_nir, from_nir, read_nir, to_nir

    model = _learned_snn6(2)
    path = save_checkpoint(tmp_path / "lt.pt", model, name="snn6",
                           model_kwargs={"learn_tau": True}, input_spec=SPEC)  # fmt: skip
    back, (height, width) = read_nir(export_nir(path, tmp_path / "lt.nir"))
    assert back.learn_tau and (height, width) == (64, 80)
    for name, taus in model.time_constants().items():
        for key, value in taus.items():
            assert back.time_constants()[name][key] == pytest.approx(value, rel=1e-6)
    graph = to_nir(model, 64, 80)
    assert float(graph.nodes["lif2"].tau_syn.flat[0]) == pytest.approx(5e-3, rel=1e-6)
    assert graph.nodes["lif2"].metadata["spikegyro"]["tau_r_ms"] == pytest.approx(1.5)
    graph.nodes["lif4"].metadata["spikegyro"]["tau_r_ms"] = 40.0
    with pytest.raises(Exception, match=r"lif4.*\(0.5, 32\) ms"):
        from_nir(graph)
    assert not from_nir(to_nir(SNN6(), 64, 80))[0].learn_tau


def test_learned_tau_moves_under_training():
    """A few Adam steps on a readout-only target change every τ (they receive gradient)."""
    model = SNN6(learn_tau=True)
    model.set_surrogate_cut(0.2)
    model.use_event_engine(1)
    x = _window((2, 2, 64, 80, 40), 0.05).float()
    y = torch.full((2, 3, 40), 0.5)
    before = {k: dict(v) for k, v in model.time_constants().items()}
    optimizer = torch.optim.Adam(model.tau_parameters(), lr=1e-2)
    for _ in range(3):
        optimizer.zero_grad()
        angular_velocity_loss(model(x), y, 10).backward()
        optimizer.step()
    after = model.time_constants()
    moved = [math.isclose(after[n][k], v) for n in before for k, v in before[n].items()]
    assert not any(moved)


# ------------------------------------------------------------------------------ train


def test_train_learn_tau_carries_tau_through_init_checkpoints_resume_and_predict(
    tiny_dataset,  # noqa: F811  (the fixture imported above)
    tmp_path,
    monkeypatch,
):
    from test_train_loop import tiny_config

    from spikegyro.stream.model import load_streaming_model
    from spikegyro.train.loop import resume_config, train

    monkeypatch.setenv("SPIKEGYRO_CACHE", str(tmp_path / "cache"))
    dataset = tiny_dataset
    train(tiny_config(dataset, tmp_path / "a", iterations=1), progress=False)
    config = tiny_config(dataset, tmp_path / "b", init=str(tmp_path / "a" / "last.pt"),
                         learn_tau=True, compute="sparse", iterations=3, lr=3e-3)  # fmt: skip
    train(config, progress=False)
    payload = torch.load(tmp_path / "b" / "last.pt", weights_only=False)
    assert payload["model_kwargs"]["learn_tau"] is True
    model, _ = load_checkpoint(tmp_path / "b" / "last.pt")
    taus = model.time_constants()
    assert not math.isclose(taus["conv5"]["tau_r"], 4.0) and not math.isclose(
        taus["fc"]["tau_s"], 8
    )
    engine, _ = load_streaming_model(tmp_path / "b" / "last.pt")
    assert len(engine.spec.layers[4].ref_kernel) == model.conv5.ref_kernel.numel()
    with pytest.raises(Exception, match="learn_tau"):
        resume_config(tmp_path / "b", {"learn_tau": False})
