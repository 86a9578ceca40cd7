"""SRM layers: official layer order, a single neuron by hand, pooling, and learning."""

import math

import pytest
import torch
import torch.nn.functional as F

from spikegyro.snn.functional import psp, spike_fn
from spikegyro.snn.layers import GASP, SRMConv, SRMDense, SRMParams

PARAMS = SRMParams(tau_s=2.0, theta=0.27, tau_r=1.0, scale_rho=0.2)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_srm_conv_equals_official_order_spike_of_conv_of_psp():
    # The official model computes spike(conv(psp(x))); the layer convolves first. Same spikes.
    gen = torch.Generator().manual_seed(3)
    x = (torch.rand(2, 2, 17, 21, 40, generator=gen) < 0.1).double()
    layer = SRMConv(2, 4, PARAMS, kernel_size=3, stride=2).double()
    with torch.no_grad():
        layer.weight.mul_(3.0)
        filtered = psp(x, layer.srm_kernel)
        current = torch.stack(
            [F.conv2d(filtered[..., t], layer.weight, stride=2) for t in range(40)], dim=-1
        )
        expected = spike_fn(current, PARAMS.theta, layer.ref_kernel, PARAMS.scale_rho)
        got = layer(x)
    assert got.shape == (2, 4, 8, 10, 40)
    assert expected.sum() > 10  # the comparison is not between two silent layers
    assert torch.equal(got, expected)


def test_single_neuron_spikes_at_the_analytic_step():
    # One input spike at t0 through weight w gives v[t0 + k] = w·ε[k]; with τs = 4, θ = 0.3 and
    # w = 0.5 the first k with w·(k/4)·e^(1 − k/4) ≥ θ is k = 2 (0.26 at k = 1, 0.41 at k = 2).
    params = SRMParams(tau_s=4.0, theta=0.3, tau_r=4.0, scale_rho=1.0)
    neuron = SRMDense(1, 1, params)
    with torch.no_grad():
        neuron.weight.fill_(0.5)
    x = torch.zeros(1, 1, 30)
    t0 = 5
    x[0, 0, t0] = 1.0
    first = next(k for k in range(1, 30) if 0.5 * k / 4 * math.exp(1 - k / 4) >= 0.3)
    assert first == 2
    spikes = neuron(x)[0, 0]
    # After the spike, ν[1] = −0.6 pushes u = 0.5·ε[k] + ν below θ for the rest of the bump.
    assert torch.nonzero(spikes).flatten().tolist() == [t0 + first]


def test_readout_is_the_psp_of_the_weighted_input():
    readout = SRMDense(3, 2, SRMParams(tau_s=8.0))
    x = torch.rand(4, 3, 50)
    expected = psp(torch.einsum("oc,nct->not", readout.weight, x), readout.srm_kernel)
    torch.testing.assert_close(readout(x), expected)


def test_gasp_is_the_spatial_mean_per_step():
    x = (torch.rand(2, 5, 4, 6, 9) < 0.3).float()
    pooled = GASP()(x)
    assert pooled.shape == (2, 5, 9)
    torch.testing.assert_close(pooled[1, 2, 3], x[1, 2, :, :, 3].sum() / 24)


@pytest.mark.parametrize(("batch", "steps"), [(1, 1), (3, 257)])
def test_any_batch_and_length(batch, steps):
    layer = SRMConv(2, 3, PARAMS, stride=1)
    out = layer(torch.rand(batch, 2, 5, 6, steps).round())
    assert out.shape == (batch, 3, 3, 4, steps)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    gen = torch.Generator().manual_seed(0)
    x = (torch.rand(2, 2, 20, 20, 60, generator=gen) < 0.2).float()
    layer = SRMConv(2, 4, PARAMS, stride=2)
    with torch.no_grad():
        layer.weight.mul_(3.0)
    cpu = layer(x)
    gpu = layer.cuda()(x.cuda()).cpu()
    assert (cpu != gpu).float().mean() < 1e-3


def test_small_network_learns_to_track_a_trajectory():
    torch.manual_seed(0)
    steps, inputs = 100, 20
    x = (torch.rand(2, inputs, steps) < 0.1).float()
    t = torch.arange(steps, dtype=torch.float32)
    target = torch.stack([torch.sin(2 * math.pi * t / 50), 0.5 * torch.cos(2 * math.pi * t / 80)])
    target = target[:, None, :]  # (2 samples, 1 output, T)
    hidden = SRMDense(inputs, 32, SRMParams(tau_s=4.0, theta=0.3, tau_r=4.0, scale_rho=1.0))
    readout = SRMDense(32, 1, SRMParams(tau_s=8.0))
    hidden.reset_parameters(gain=3.0)
    # Only the spiking layer learns (through the surrogate); the readout stays as drawn.
    optimizer = torch.optim.Adam([hidden.weight], lr=0.02)
    losses = []
    for _ in range(150):
        loss = F.mse_loss(readout(hidden(x)), target)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert min(losses[-10:]) < 0.05 * losses[0]
