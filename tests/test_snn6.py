"""SNN-6: shapes, input checks, an independent step-by-step reference, checkpoints."""

import argparse

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from spikegyro.errors import InputError
from spikegyro.models.official import load_official
from spikegyro.models.registry import build_model, load_checkpoint, save_checkpoint
from spikegyro.models.snn6 import SNN6, SNN6_LAYERS

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _spikes(shape, density, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(shape, generator=gen) < density).float()


def _reference_forward(model: SNN6, x: torch.Tensor) -> torch.Tensor:
    """docs/snn.md's equations one step at a time, in the official order conv(psp(s)), float64."""
    steps = x.shape[-1]
    s_in = [x[..., t].double() for t in range(steps)]
    for conv, spec in zip(model.convs, SNN6_LAYERS, strict=True):
        p = spec.params
        k = np.arange(200)
        eps = k / p.tau_s * np.exp(1 - k / p.tau_s)
        eps = eps[: np.nonzero((eps < 0.01) & (k > p.tau_s))[0][0]]
        nu = -2 * p.theta * np.exp(-(k - 1) / p.tau_r)
        nu = np.concatenate([[0.0], nu[1:][np.abs(nu[1:]) > 0.01]])
        w = conv.weight.detach().double()
        s_out, refractory = [], {}
        for t in range(steps):
            filtered = sum(eps[j] * s_in[t - j] for j in range(min(len(eps), t + 1)))
            u = F.conv2d(filtered, w, stride=spec.stride) + refractory.pop(t, 0.0)
            s = (u >= p.theta).double()
            for j in range(1, len(nu)):
                refractory[t + j] = refractory.get(t + j, 0.0) + nu[j] * s
            s_out.append(s)
        s_in = s_out
    k = np.arange(200)
    eps8 = k / 8 * np.exp(1 - k / 8)
    eps8 = eps8[: np.nonzero((eps8 < 0.01) & (k > 8))[0][0]]
    y = [F.linear(s.mean(dim=(2, 3)), model.fc.weight.double()) for s in s_in]
    out = [sum(eps8[j] * y[t - j] for j in range(min(len(eps8), t + 1))) for t in range(steps)]
    return torch.stack(out, dim=-1)


def test_forward_equals_step_by_step_reference():
    model = SNN6().double()
    x = _spikes((2, 2, 70, 66, 30), 0.03)
    out, spikes = model.forward_with_spikes(x.double())
    assert spikes[-1].sum() > 0
    # The model's kernels are float32 values (as in the official buffers): agreement to ~1e-7.
    torch.testing.assert_close(out, _reference_forward(model, x), rtol=1e-5, atol=1e-6)


def test_shapes_batch_one_and_layer_spikes():
    model = SNN6()
    x = _spikes((1, 2, 90, 120, 25), 0.02)
    out, spikes = model.forward_with_spikes(x)
    assert out.shape == (1, 3, 25)
    torch.testing.assert_close(model(x), out)
    assert [s.shape[1] for s in spikes] == [16, 32, 64, 128, 256]
    assert spikes[-1].shape[2:4] == model.feature_size(90, 120) == (2, 4)
    assert all(s.shape[-1] == 25 for s in spikes)


def test_fresh_network_is_alive_on_realistic_input():
    for density in (0.01, 0.02):
        _, spikes = SNN6().forward_with_spikes(_spikes((2, 2, 72, 96, 40), density, seed=7))
        assert spikes[-1][..., 20:].mean() > 0.005, density


def test_small_or_malformed_input_is_rejected():
    model = SNN6()
    assert model.min_input_size() == 63
    assert model(_spikes((1, 2, 63, 63, 5), 0.1)).shape == (1, 3, 5)
    with pytest.raises(InputError, match="63x63"):
        model(torch.zeros(1, 2, 62, 100, 5))
    with pytest.raises(InputError, match="expected"):
        model(torch.zeros(2, 90, 120, 5))


def test_gradients_reach_every_layer():
    model = SNN6()
    out = model(_spikes((1, 2, 72, 96, 30), 0.02))
    out[..., 15:].pow(2).mean().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_registry_checkpoint_round_trip(tmp_path):
    model = build_model("snn6")
    path = save_checkpoint(
        tmp_path / "m.pt", model, name="snn6", model_kwargs={}, input_spec={"sensor": [96, 72]}
    )
    loaded, _ = load_checkpoint(path)
    x = _spikes((1, 2, 72, 96, 20), 0.03)
    torch.testing.assert_close(loaded(x), model(x))


def _official_state(model: SNN6) -> dict[str, torch.Tensor]:
    state = {}
    for i, conv in enumerate(model.convs, 1):
        state[f"conv{i}.weight"] = conv.weight.detach().clone()[..., None]
        state[f"slayer_conv{i}.srmKernel"] = conv.srm_kernel.clone()
        state[f"slayer_conv{i}.refKernel"] = conv.ref_kernel.clone()
    state["fc.weight"] = model.fc.weight.detach().clone()[:, :, None, None, None]
    state["slayer_fc.srmKernel"] = model.fc.srm_kernel.clone()
    state["slayer_fc.refKernel"] = torch.tensor([0.0, -20.0, -7.4])
    return state


def test_official_checkpoint_reproduces_the_model(tmp_path):
    model = SNN6()
    state = _official_state(model)
    assert state["conv1.weight"].shape == (16, 2, 3, 3, 1)
    assert state["fc.weight"].shape == (3, 256, 1, 1, 1)
    path = tmp_path / "official.pth"
    torch.save({"model_state_dict": state, "epoch": 3}, path)
    x = _spikes((1, 2, 72, 96, 30), 0.02)
    expected = model(x)
    for stored in (False, True):
        loaded = load_official(path, use_stored_kernels=stored)
        torch.testing.assert_close(loaded(x), expected)
    # DataParallel's 'module.' prefix is accepted.
    torch.save({"model_state_dict": {f"module.{k}": v for k, v in state.items()}}, path)
    torch.testing.assert_close(load_official(path)(x), expected)


def test_official_stored_kernels_are_used_on_request(tmp_path):
    model = SNN6()
    state = _official_state(model)
    state["slayer_fc.srmKernel"] = torch.tensor([0.0, 1.0])  # a one-step delay
    path = tmp_path / "official.pth"
    torch.save({"model_state_dict": state}, path)
    x = _spikes((1, 2, 72, 96, 20), 0.03)
    out = load_official(path, use_stored_kernels=True)(x)
    _, spikes = model.forward_with_spikes(x)
    pooled = F.linear(spikes[-1].mean(dim=(2, 3)).transpose(1, 2), model.fc.weight).transpose(1, 2)
    torch.testing.assert_close(out[..., 1:], pooled[..., :-1])
    assert torch.all(out[..., 0] == 0)


def test_official_mismatches_are_named(tmp_path):
    state = _official_state(SNN6())
    state["conv3.weight"] = state["conv3.weight"][:32]
    del state["fc.weight"]
    state["conv6.weight"] = torch.zeros(1)
    path = tmp_path / "bad.pth"
    torch.save({"model_state_dict": state}, path)
    with pytest.raises(InputError) as err:
        load_official(path)
    message = str(err.value)
    assert "missing fc.weight" in message
    assert "unexpected conv6.weight" in message
    assert "conv3.weight (32, 32, 3, 3, 1) (expected (64, 32, 3, 3, 1))" in message
    with pytest.raises(InputError, match="no such"):
        load_official(tmp_path / "none.pth")
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable"):
        load_official(path)


def test_official_checkpoint_with_pickled_extras_loads(tmp_path):
    model = SNN6()
    path = tmp_path / "official.pth"
    # Non-tensor extras (a config object) are refused by weights_only loading; still readable.
    extras = argparse.Namespace(lr=1e-4)
    torch.save({"model_state_dict": _official_state(model), "config": extras}, path)
    torch.testing.assert_close(load_official(path).conv2.weight, model.conv2.weight)
