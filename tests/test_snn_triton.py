"""The fused Triton spike kernels against the torch reference in spikegyro.snn.functional.

On a GPU the compiled kernels run on CUDA tensors; without one, Triton's interpreter
(TRITON_INTERPRET=1) runs the same kernels on CPU tensors. Skipped where Triton is not installed
(``pip install spikegyro[gpu]``). The reference is the torch code, forced with SPIKEGYRO_TRITON=0.
"""

from __future__ import annotations

import importlib
import os
import sys

import pytest
import torch

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"

if DEVICE == "cpu":
    # Triton builds its language as the interpreter's or the compiler's when it is imported.
    if "triton" in sys.modules and os.environ.get("TRITON_INTERPRET") != "1":
        pytest.skip("triton was imported before its interpreter could be enabled",
                    allow_module_level=True)  # fmt: skip
    os.environ["TRITON_INTERPRET"] = "1"
    try:
        pytest.importorskip("triton")
    finally:
        del os.environ["TRITON_INTERPRET"]  # the fixture enables it per test only
else:
    pytest.importorskip("triton")

from spikegyro.models.snn6 import SNN6  # noqa: E402
from spikegyro.snn import functional  # noqa: E402
from spikegyro.snn.kernels import refractory_kernel  # noqa: E402


@pytest.fixture
def kernels(monkeypatch):
    """The triton_kernels module, compiled on CUDA or interpreted on the CPU."""
    if DEVICE == "cpu":
        monkeypatch.setenv("TRITON_INTERPRET", "1")
    module = sys.modules.get("spikegyro.snn.triton_kernels")
    if module is None:
        module = importlib.import_module("spikegyro.snn.triton_kernels")
    elif ("Interpreted" in type(module._fire_kernel).__name__) != (DEVICE == "cpu"):
        module = importlib.reload(module)  # the kernels are built when the module is imported
    functional._triton_module.cache_clear()
    yield module
    functional._triton_module.cache_clear()


def reference(monkeypatch, fn, *args, **kw):
    """``fn`` run by the torch code."""
    with monkeypatch.context() as m:
        m.setenv("SPIKEGYRO_TRITON", "0")
        return fn(*args, **kw)


def busy_potential(steps: int, m: int, theta: float, seed: int = 0) -> torch.Tensor:
    """Potentials that cross θ often, so neurons fire in bursts and refractoriness matters."""
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(steps, m, generator=g) * 2.5 * theta).to(DEVICE)


@pytest.mark.parametrize(("theta", "tau_r"), [(0.27, 1.0), (0.4, 4.0)])
@pytest.mark.parametrize("layout", ["contiguous", "transposed", "in_place"])
def test_fused_fire_is_bit_identical_to_the_torch_recursion(
    kernels, monkeypatch, theta, tau_r, layout
):
    ref_kernel = refractory_kernel(theta, tau_r)
    rows = busy_potential(37, 300, theta)
    if layout == "transposed":  # time-last storage seen as (T, M), as _TimeRows hands it over
        rows = rows.t().contiguous().t()
    expected_spikes, expected_potential = reference(
        monkeypatch, functional._fire_rows, rows, theta, ref_kernel
    )
    assert functional._fused(rows, ref_kernel) is kernels
    source = rows.clone()
    spikes, potential = functional._fire_rows(
        source, theta, ref_kernel, in_place=layout == "in_place"
    )
    assert torch.equal(spikes, expected_spikes) and torch.equal(potential, expected_potential)
    assert 0.05 < float(spikes.mean()) < 0.9
    if layout == "in_place":
        assert potential.data_ptr() == source.data_ptr()
    else:
        assert torch.equal(source, rows)


def test_fused_surrogate_backward_matches_rho_times_grad(kernels):
    potential = busy_potential(20, 513, 0.3, seed=1)
    grad = torch.randn(20, 513, device=DEVICE)
    rho = functional.surrogate_gradient(potential.clone(), 0.3, 0.13) * grad
    fused = kernels.surrogate_backward(potential, grad, 0.3, 0.13, functional.TAU_RHO)
    torch.testing.assert_close(fused, rho, rtol=1e-5, atol=1e-7)  # tl.exp may use ex2.approx


def test_snn6_step_through_the_fused_kernels_matches_the_reference(kernels, monkeypatch):
    """Forward output exactly, gradients of every layer within float rounding.

    On a GPU, cuDNN's weight gradients sum in a run-dependent order and ``tl.exp`` may be
    ex2.approx, so gradients are compared by their relative norm, the size float rounding
    accumulated over six layers' backward gives, not element by element.
    """
    if DEVICE == "cuda":
        monkeypatch.setattr(torch.backends.cudnn, "deterministic", True)
        monkeypatch.setattr(torch.backends.cudnn, "benchmark", False)
    torch.manual_seed(0)
    model = SNN6().to(DEVICE)
    x = (torch.rand(2, 2, 64, 64, 16, device=DEVICE) < 0.1).float()

    def step():
        model.zero_grad(set_to_none=True)
        out, spikes = model.forward_with_spikes(x)
        out[..., 8:].pow(2).mean().backward()
        grads = [p.grad.clone() for p in model.parameters()]
        return out.detach(), [s.detach().sum() for s in spikes], grads

    expected = reference(monkeypatch, step)
    got = step()
    assert all(float(s) > 0 for s in expected[1][:4]), "layers must fire for a real check"
    assert torch.equal(got[0], expected[0])
    assert [float(s) for s in got[1]] == [float(s) for s in expected[1]]
    for g, e in zip(got[2], expected[2], strict=True):
        assert float(e.norm()) > 0
        assert float((g - e).norm()) <= 1e-4 * float(e.norm())


def test_torch_code_runs_where_triton_is_not_asked_for(monkeypatch):
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    assert functional._fused(torch.zeros(3, 4)) is None  # CPU tensors: the torch code
    if torch.cuda.is_available():
        assert functional._fused(torch.zeros(3, 4, device="cuda", dtype=torch.float64)) is None
