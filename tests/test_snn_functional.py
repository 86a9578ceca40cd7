"""psp, spike function and surrogate gradient against direct computations and hand analysis."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from spikegyro.snn.functional import conv_over_time, fire, psp, spike_fn, surrogate_gradient
from spikegyro.snn.kernels import refractory_kernel, srm_kernel


def _direct_psp(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Causal convolution along the last axis by np.convolve, one train at a time."""
    steps = x.shape[-1]
    rows = [np.convolve(r, kernel)[:steps] for r in x.reshape(-1, steps)]
    return np.stack(rows).reshape(x.shape)


@pytest.mark.parametrize("steps", [1, 7, 100, 300])
@pytest.mark.parametrize("tau_s", [2.0, 8.0])
def test_psp_equals_direct_convolution(steps, tau_s):
    gen = torch.Generator().manual_seed(steps)
    x = (torch.rand(2, 3, 4, steps, generator=gen) < 0.2).double()
    kernel = srm_kernel(tau_s).double()
    expected = _direct_psp(x.numpy(), kernel.numpy())
    np.testing.assert_allclose(psp(x, kernel).numpy(), expected, atol=1e-12)
    # Same result with time first, and on a non-contiguous view.
    time_first = psp(x.permute(3, 0, 1, 2), kernel, dim=0).permute(1, 2, 3, 0)
    np.testing.assert_allclose(time_first.numpy(), expected, atol=1e-12)
    sliced = x[:, ::2]
    np.testing.assert_allclose(psp(sliced, kernel).numpy(), expected[:, ::2], atol=1e-12)


def test_psp_single_spike_is_the_kernel():
    kernel = srm_kernel(4.0)
    x = torch.zeros(60)
    x[10] = 1.0
    y = psp(x, kernel)
    n = kernel.numel()
    assert torch.equal(y[:10], torch.zeros(10))
    torch.testing.assert_close(y[10 : 10 + n], kernel)
    assert torch.all(y[10 + n :] == 0)


@pytest.mark.parametrize("steps", [20, 150])
def test_psp_gradcheck(steps):
    x = torch.randn(3, steps, dtype=torch.float64, requires_grad=True)
    kernel = srm_kernel(4.0).double()
    assert torch.autograd.gradcheck(lambda a: psp(a, kernel), (x,), fast_mode=steps > 100)


def test_spike_fn_constant_drive_fires_every_other_step():
    # θ = 0.27, τr = 1: ν = [0, −0.54, −0.199, −0.073, −0.027]. A constant drive c = 0.5 fires at
    # t = 0; at odd steps u = 0.5 − 0.54 (− 0.073) < θ; at even steps u = 0.5 − 0.199 (− 0.027)
    # = 0.274 ≥ θ. So the neuron spikes exactly at the even steps.
    theta = 0.27
    nu = refractory_kernel(theta, 1.0)
    steps = 30
    spikes = spike_fn(torch.full((1, steps), 0.5), theta, nu, scale_rho=0.2)
    expected = (torch.arange(steps) % 2 == 0).float()
    assert torch.equal(spikes[0], expected)


def test_potential_drops_by_exactly_nu_after_a_spike():
    theta = 0.4
    nu = refractory_kernel(theta, 4.0)
    v = torch.full((50,), 0.1)
    v[5] = 1.0
    spikes, u = fire(v, theta, nu)
    assert torch.nonzero(spikes).flatten().tolist() == [5]
    n = nu.numel()
    torch.testing.assert_close(u[5 : 5 + n] - v[5 : 5 + n], nu, rtol=0, atol=1e-7)
    assert torch.equal(u[:5], v[:5]) and torch.equal(u[5 + n :], v[5 + n :])


def test_spike_fn_threshold_is_inclusive():
    spikes = spike_fn(torch.tensor([0.3, 0.29999, 0.3]), 0.3, torch.zeros(1), scale_rho=1.0, dim=0)
    assert spikes.tolist() == [1.0, 0.0, 1.0]


@pytest.mark.parametrize(("theta", "scale_rho"), [(0.27, 0.2), (0.4, 100.0)])
def test_surrogate_gradient_matches_formula(theta, scale_rho):
    tau_rho = 0.3
    gen = torch.Generator().manual_seed(0)
    v = (torch.rand(8, 40, generator=gen) * 2 * theta).requires_grad_(True)
    nu = refractory_kernel(theta, 4.0)
    g = torch.randn(8, 40, generator=gen)
    (spike_fn(v, theta, nu, scale_rho, tau_rho) * g).sum().backward()
    _, u = fire(v.detach(), theta, nu)
    assert not torch.equal(u, v.detach())  # some neurons fired, so ρ is taken at u, not v
    rho = [scale_rho / theta * math.exp(-abs(ui - theta) / (tau_rho * theta)) for ui in u.flatten()]
    expected = torch.tensor(rho).reshape(u.shape) * g
    torch.testing.assert_close(v.grad, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(
        surrogate_gradient(u, theta, scale_rho, tau_rho), torch.tensor(rho).reshape(u.shape)
    )


@pytest.mark.parametrize("binary", [True, False])
def test_conv_over_time_equals_per_step_conv_including_gradients(binary):
    gen = torch.Generator().manual_seed(1)
    x = torch.rand(6, 2, 3, 20, 24, generator=gen)
    x = (x < 0.1).float() if binary else x * 3  # graded input must not go through booleans
    w = torch.randn(5, 3, 3, 3, generator=gen, requires_grad=True)
    y = conv_over_time(x, w, stride=2, binary=binary)
    g = torch.randn(y.shape, generator=gen)
    (y * g).sum().backward()
    w_ref = w.detach().clone().requires_grad_(True)
    y_ref = torch.stack([F.conv2d(x[t], w_ref, stride=2) for t in range(6)])
    (y_ref * g).sum().backward()
    torch.testing.assert_close(y, y_ref)
    torch.testing.assert_close(w.grad, w_ref.grad, rtol=1e-4, atol=1e-4)  # summation order


def test_spike_fn_overwrite_matches_and_leaves_the_full_potential():
    theta, nu = 0.3, refractory_kernel(0.3, 4.0)
    gen = torch.Generator().manual_seed(2)
    base = torch.rand(30, 50, generator=gen) * 0.6
    g = torch.randn(30, 50, generator=gen)
    results = []
    for overwrite in (False, True):
        w = torch.ones((), requires_grad=True)
        v = base * w  # an intermediate, like a layer's potential
        spikes = spike_fn(v, theta, nu, scale_rho=0.5, dim=0, overwrite=overwrite)
        (spikes * g).sum().backward()
        results.append((spikes.detach(), w.grad.clone(), v.detach().clone()))
    (s0, g0, v0), (s1, g1, v1) = results
    assert torch.equal(s0, s1) and s0.sum() > 0
    torch.testing.assert_close(g0, g1)
    torch.testing.assert_close(v0, base)  # untouched without overwrite
    torch.testing.assert_close(v1, fire(base, theta, nu, dim=0)[1])  # ν added in place
