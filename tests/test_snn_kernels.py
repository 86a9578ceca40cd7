"""SRM kernels against their closed forms and the official truncation rules."""

import math

import numpy as np
import pytest
import torch

from spikegyro.snn.kernels import refractory_kernel, srm_kernel


@pytest.mark.parametrize("tau_s", [1.0, 2.0, 4.0, 8.0, 2.5])
def test_srm_kernel_closed_form_and_truncation(tau_s):
    eps = srm_kernel(tau_s).double().numpy()
    k = np.arange(eps.size)
    np.testing.assert_allclose(eps, k / tau_s * np.exp(1 - k / tau_s), rtol=1e-6, atol=1e-7)
    assert eps[0] == 0.0
    # The first dropped tap is the first k > τs with ε < 0.01; every kept tap beyond τs is ≥ 0.01.
    n = eps.size
    assert n > tau_s and n / tau_s * math.exp(1 - n / tau_s) < 0.01
    assert np.all(eps[k > tau_s] >= 0.01)


def test_srm_kernel_known_values():
    eps = srm_kernel(2.0)
    assert eps.numel() == 16  # ε[15] = 7.5·e^-6.5 ≈ 0.0113 kept, ε[16] = 8·e^-7 ≈ 0.0073 dropped
    assert float(eps[2]) == pytest.approx(1.0)  # peak 1 at k = τs
    assert float(eps[1]) == pytest.approx(0.5 * math.exp(0.5))


@pytest.mark.parametrize(("theta", "tau_r"), [(0.27, 1.0), (0.25, 1.0), (0.4, 4.0), (1.0, 2.0)])
def test_refractory_kernel_closed_form_and_truncation(theta, tau_r):
    nu = refractory_kernel(theta, tau_r).double().numpy()
    assert nu[0] == 0.0
    k = np.arange(1, nu.size)
    np.testing.assert_allclose(nu[1:], -2 * theta * np.exp(-(k - 1) / tau_r), rtol=1e-6)
    assert np.all(np.abs(nu[1:]) > 0.01)
    assert 2 * theta * math.exp(-(nu.size - 1) / tau_r) <= 0.01  # the next tap is dropped


def test_refractory_kernel_known_length():
    # θ = 0.27, τr = 1: −0.54·e^−j for j = 0..3 kept (|·| ≥ 0.0269), j = 4 gives 0.0099 dropped.
    assert refractory_kernel(0.27, 1.0).numel() == 5
    assert float(refractory_kernel(0.27, 1.0)[1]) == pytest.approx(-0.54)


def test_kernels_reject_nonpositive_constants():
    with pytest.raises(ValueError):
        srm_kernel(0.0)
    with pytest.raises(ValueError):
        refractory_kernel(0.3, -1.0)


@pytest.mark.parametrize("tau_s", [1.0, 2.0, 4.0])
def test_float64_kernels_are_exact_and_float32_ones_rounded(tau_s):
    eps64 = srm_kernel(tau_s, dtype=torch.float64).numpy()
    k = np.arange(eps64.size)
    np.testing.assert_allclose(eps64, k / tau_s * np.exp(1 - k / tau_s), rtol=1e-15, atol=0)
    widened = srm_kernel(tau_s).double().numpy()
    assert widened.size == eps64.size
    rel = np.abs(widened - eps64)[1:] / eps64[1:]
    assert 0 < rel.max() <= 2.0**-24  # half a float32 ulp
    nu64 = refractory_kernel(0.4, tau_s, dtype=torch.float64).numpy()
    j = np.arange(nu64.size - 1)
    np.testing.assert_allclose(nu64[1:], -0.8 * np.exp(-j / tau_s), rtol=1e-15, atol=0)
