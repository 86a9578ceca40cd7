"""Small spiking networks and synthetic event streams for the streaming tests."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from spikegyro.events.core import EventArray
from spikegyro.snn.layers import GASP, SRMConv, SRMDense, SRMParams


class TinySNN(nn.Module):
    """Three spiking conv layers (strides 2, 2, 1; mixed time constants), GASP, dense readout."""

    def __init__(self, gain: float = 3.0, seed: int = 0) -> None:
        super().__init__()
        torch.manual_seed(seed)
        self.conv1 = SRMConv(2, 8, SRMParams(tau_s=2, theta=0.27, tau_r=1), stride=2)
        self.conv2 = SRMConv(8, 16, SRMParams(tau_s=4, theta=0.3, tau_r=4), stride=2)
        self.conv3 = SRMConv(16, 16, SRMParams(tau_s=3, theta=0.4, tau_r=2), stride=1)
        self.pool = GASP()
        self.fc = SRMDense(16, 3, SRMParams(tau_s=8))
        for layer in (self.conv1, self.conv2, self.conv3):
            layer.reset_parameters(gain)

    def forward_with_spikes(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        s1 = self.conv1(x)
        s2 = self.conv2(s1)
        s3 = self.conv3(s2)
        return self.fc(self.pool(s3)), [s1, s2, s3]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_with_spikes(x)[0]


def exact_double(model: nn.Module) -> nn.Module:
    """``model`` in float64 with its kernels recomputed in float64 (not widened from float32):
    the batch forward that the float64 streaming engine must equal to the last bits."""
    model.double()
    for layer in model.modules():
        if hasattr(layer, "exact_kernels"):
            layer.exact_kernels()
    return model


def random_events(
    width: int, height: int, duration_ms: int, rate: float, seed: int = 0, t0_us: int = 0
) -> EventArray:
    """Uniform random events: ``rate`` events per pixel per ms, sorted, µs timestamps."""
    rng = np.random.default_rng(seed)
    n = int(rate * width * height * duration_ms)
    t = np.sort(rng.integers(0, duration_ms * 1000, n)) + t0_us
    return EventArray.from_arrays(
        rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n),
        width, height,
    )  # fmt: skip


def step_offsets(events: EventArray, t0_us: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(flat input index, per-step offsets) of events binned at 1 ms from ``t0_us``."""
    k = (events.t - t0_us) // 1000
    index = (events.y.astype(np.int64) * events.width + events.x) * 2 + events.p
    return index, np.searchsorted(k, np.arange(steps + 1))
