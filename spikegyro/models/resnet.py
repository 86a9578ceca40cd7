"""ResNet-50 (He et al., 2016) for event images, without torchvision.

The standard bottleneck network (expansion 4, stages of 3-4-6-3 blocks, stride on the 3x3
convolution as in torchvision's "v1.5"): stem 7x7/2 convolution + batch norm + ReLU + 3x3/2 max
pooling, four stages, global average pooling and a linear layer. Only the stem's input channels
and the number of outputs change with the task; built with ``in_channels=3, num_outputs=1000``
it has exactly the 25,557,032 parameters of the ImageNet ResNet-50.

Used in the paper on two inputs: (A) two-channel accumulated event frames and (V) voxel grids;
the output is the mean angular velocity over the input window, rad/s.
"""

from __future__ import annotations

import torch
from torch import nn

from spikegyro.models.registry import register

EXPANSION = 4
STAGE_BLOCKS = (3, 4, 6, 3)
STAGE_WIDTHS = (64, 128, 256, 512)


class Bottleneck(nn.Module):
    """1x1 reduce, 3x3 (carrying the stride), 1x1 expand; identity or projection shortcut."""

    def __init__(self, in_channels: int, width: int, stride: int) -> None:
        super().__init__()
        out_channels = width * EXPANSION
        self.conv1 = nn.Conv2d(in_channels, width, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, width, 3, stride=stride, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(width)
        self.conv3 = nn.Conv2d(width, out_channels, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(out_channels)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_channels != out_channels:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False),
                nn.BatchNorm2d(out_channels),
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        return self.relu(y + self.shortcut(x))


def make_stage(in_channels: int, width: int, blocks: int, stride: int) -> nn.Sequential:
    """``blocks`` bottlenecks; the first one changes resolution and channel count."""
    layers = [Bottleneck(in_channels, width, stride)]
    layers += [Bottleneck(width * EXPANSION, width, 1) for _ in range(blocks - 1)]
    return nn.Sequential(*layers)


@register("resnet50")
class ResNet50(nn.Module):
    """ResNet-50: ``forward(x (N, in_channels, H, W)) -> (N, num_outputs)``.

    Args:
        in_channels: input planes (2 for accumulated frames, the bin count for voxel grids).
        num_outputs: regression outputs (3: ω_x, ω_y, ω_z in rad/s).
    """

    def __init__(self, in_channels: int, num_outputs: int = 3) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, STAGE_WIDTHS[0], 7, stride=2, padding=3, bias=False),
            nn.BatchNorm2d(STAGE_WIDTHS[0]),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, stride=2, padding=1),
        )
        stages = []
        channels = STAGE_WIDTHS[0]
        for i, (width, blocks) in enumerate(zip(STAGE_WIDTHS, STAGE_BLOCKS, strict=True)):
            stages.append(make_stage(channels, width, blocks, stride=1 if i == 0 else 2))
            channels = width * EXPANSION
        self.stages = nn.Sequential(*stages)
        self.fc = nn.Linear(channels, num_outputs)
        self._init_weights()

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        # Each residual branch starts as zero (Goyal et al., 2017), so the untrained network is
        # a shallow stack of shortcuts; this keeps early regression outputs small and stable.
        for m in self.modules():
            if isinstance(m, Bottleneck):
                nn.init.zeros_(m.bn3.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.stages(self.stem(x)).mean(dim=(2, 3)))
