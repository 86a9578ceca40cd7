"""ANN-6: the SNN-6 layout as a conventional frame network (the paper's ANN baseline).

Five 3x3 convolutions without padding (channels 16-32-64-128-256, strides 2-2-2-2-1), ReLU,
global average pooling and a linear 256 -> 3 readout, as in the paper's Table I with the spiking
neurons replaced by ReLU (Sec. V). The input is one event window as a dense image stack, e.g. a
voxel grid of a 20 ms window (``in_channels`` = number of time bins); the output is the mean
angular velocity over that window.

Normalization: each convolution is followed by batch normalization by default (the paper does
not say). Voxel grids hold signed event counts whose scale grows with the rotation speed, so the
activations of an unnormalized stack change scale from window to window; batch norm removes that.
Measured (BENCHMARKS.md, "ANN baselines"): with the same 150-step ``cpu`` schedule, held-out
median relative error 0.70 with batch norm vs 0.96 without (the mean predictor: 0.95).
``batch_norm=False`` gives the bare layout (convolutions then carry a bias).
"""

from __future__ import annotations

import torch
from torch import nn

from spikegyro.models.registry import register

CHANNELS = (16, 32, 64, 128, 256)
STRIDES = (2, 2, 2, 2, 1)


def conv_block(in_channels: int, out_channels: int, stride: int, batch_norm: bool) -> nn.Sequential:
    """3x3 convolution without padding, optional batch norm, ReLU."""
    layers: list[nn.Module] = [
        nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=0, bias=not batch_norm)
    ]
    if batch_norm:
        layers.append(nn.BatchNorm2d(out_channels))
    layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


@register("ann6")
class ANN6(nn.Module):
    """ANN-6: ``forward(x (N, in_channels, H, W)) -> (N, num_outputs)``, rad/s.

    Args:
        in_channels: input planes (voxel-grid bins, or 2 for accumulated frames).
        num_outputs: regression outputs (3: ω_x, ω_y, ω_z).
        batch_norm: batch normalization after each convolution (see module docstring).

    The input must be at least 63x63 pixels so that the five unpadded convolutions leave a
    non-empty feature map (180x240 gives 8x12).
    """

    def __init__(self, in_channels: int, num_outputs: int = 3, batch_norm: bool = True) -> None:
        super().__init__()
        widths = (in_channels, *CHANNELS)
        self.features = nn.Sequential(
            *(
                conv_block(c_in, c_out, stride, batch_norm)
                for c_in, c_out, stride in zip(widths[:-1], widths[1:], STRIDES, strict=True)
            )
        )
        self.fc = nn.Linear(CHANNELS[-1], num_outputs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.features(x).mean(dim=(2, 3)))
