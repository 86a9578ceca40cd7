"""Operation counts and energies against hand counts and a published figure."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from spikegyro.evaluate.energy import (
    ENERGY_FIGURES,
    ann_operations,
    count_macs,
    energy,
    snn_operations,
)
from spikegyro.models.ann6 import ANN6
from spikegyro.models.resnet import ResNet50


def test_macs_of_a_small_model_by_hand():
    model = nn.Sequential(
        nn.Conv2d(2, 4, 3, stride=2, padding=1),  # 9x11 -> 5x6: 4*5*6 outputs x 2*3*3
        nn.ReLU(),
        nn.Conv2d(4, 6, 3, groups=2),  # 5x6 -> 3x4: 6*3*4 outputs x (4/2)*3*3
        nn.AdaptiveAvgPool2d(1),
        nn.Flatten(),
        nn.Linear(6, 3),  # 3 outputs x 6
    )
    expected = 4 * 5 * 6 * 18 + 6 * 3 * 4 * 18 + 3 * 6
    assert count_macs(model, torch.zeros(3, 2, 9, 11)) == expected == 3474  # per sample
    assert model.training  # restored


def test_ann6_macs_by_hand_at_240x180():
    # 180x240 -> 89x119 -> 44x59 -> 21x29 -> 10x14 -> 8x12 (3x3, no padding, strides 2,2,2,2,1)
    maps = [(89, 119), (44, 59), (21, 29), (10, 14), (8, 12)]
    channels = [5, 16, 32, 64, 128, 256]
    expected = (
        sum(
            h * w * c_out * c_in * 9
            for (h, w), c_in, c_out in zip(maps, channels[:-1], channels[1:], strict=True)
        )
        + 256 * 3
    )
    assert count_macs(ANN6(in_channels=5), torch.zeros(1, 5, 180, 240)) == expected


def test_resnet50_macs_match_the_published_figure():
    # torchvision's model table: ResNet-50 (v1.5) on 224x224 ImageNet input, 4.09 GFLOPS (MACs).
    macs = count_macs(ResNet50(in_channels=3, num_outputs=1000), torch.zeros(1, 3, 224, 224))
    assert macs == pytest.approx(4.09e9, rel=0.002)


def test_energy_of_snn_and_ann_operations_by_hand():
    snn = snn_operations({"synops_per_s": 2.0e8, "dense_macs_per_s": 5.0e10})
    assert snn["per_estimate"] == pytest.approx(2.0e5)  # one estimate per 1 ms
    e = energy(snn)
    assert e["add_fp32_45nm_uj_per_estimate"] == pytest.approx(2.0e5 * 0.9e-6)  # 0.18 µJ
    assert e["add_fp32_45nm_mw"] == pytest.approx(2.0e8 * 0.9e-12 * 1e3)  # 0.18 mW
    assert e["synop_loihi_uj_per_estimate"] == pytest.approx(2.0e5 * 23.6e-6)
    assert "mac_fp32_45nm_mw" not in e

    ann = ann_operations(1_000_000, target_ms=20)
    assert ann["per_second"] == pytest.approx(5.0e7)  # 50 estimates per second
    e = energy(ann)
    assert e["mac_fp32_45nm_uj_per_estimate"] == pytest.approx(4.6)
    assert e["mac_fp32_45nm_mw"] == pytest.approx(0.23)
    assert set(e) == {"mac_fp32_45nm_uj_per_estimate", "mac_fp32_45nm_mw"}
    assert ENERGY_FIGURES["mac_fp32_45nm"].picojoules == pytest.approx(0.9 + 3.7)  # add + mult
