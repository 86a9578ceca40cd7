"""Spike statistics: synaptic-operation counts against a brute-force convolution count."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from spikegyro.evaluate.spikes import (
    ConvGeometry,
    conv_synops,
    layer_statistics,
    receptive_counts,
)


def test_receptive_counts_by_hand():
    # 7 inputs, k=3, s=2 -> outputs see [0,3), [2,5), [4,7).
    np.testing.assert_array_equal(receptive_counts(7, 3, ConvGeometry(3, 2)), [1, 1, 2, 1, 2, 1, 1])
    # 5 inputs, k=3, s=1 -> [0,3), [1,4), [2,5).
    np.testing.assert_array_equal(receptive_counts(5, 3, ConvGeometry(3, 1)), [1, 2, 3, 2, 1])
    # 8 inputs, k=3, s=2 -> 3 outputs; the last input row is seen by none.
    np.testing.assert_array_equal(
        receptive_counts(8, 3, ConvGeometry(3, 2)), [1, 1, 2, 1, 2, 1, 1, 0]
    )


@pytest.mark.parametrize(("h", "w", "stride"), [(9, 12, 2), (8, 8, 2), (6, 7, 1)])
def test_conv_synops_equals_count_of_spike_synapse_pairs(h, w, stride):
    rng = np.random.default_rng(h * w + stride)
    spikes = torch.from_numpy((rng.random((2, 3, h, w)) < 0.3).astype(np.float64))
    c_out = 5
    # Every (input spike, weight) pair of a real convolution with an all-ones kernel.
    reference = F.conv2d(spikes, torch.ones(c_out, 3, 3, 3, dtype=torch.float64), stride=stride)
    out_shape = (c_out, *reference.shape[2:])
    counts = spikes.sum(dim=(0, 1)).numpy()
    assert conv_synops(counts, out_shape, ConvGeometry(3, stride)) == int(reference.sum())


def test_layer_statistics_rates_and_totals():
    n, t = 2, 10  # 20 ms of input
    inputs = torch.zeros(n, 2, 5, 5, t)
    inputs[0, 1, 2, 2, 3] = 1  # centre pixel: seen by all 2x2 outputs of a 3x3 stride-2 conv
    inputs[1, 0, 0, 0, 7] = 1  # corner pixel: seen by one output
    layer1 = torch.zeros(n, 4, 2, 2, t)
    layer1[0, 0, 0, 0, :4] = 1  # 4 spikes of 4*2*2 = 16 neurons
    stats = layer_statistics(inputs, [layer1], [ConvGeometry(3, 2)])
    conv1, readout = stats["layers"]
    assert stats["seconds"] == pytest.approx(0.02)
    assert stats["input_rate_hz"] == pytest.approx(2 / (25 * 0.02))
    assert conv1["synops"] == 4 * (4 + 1)  # C_out * (fan-out of centre + corner)
    assert conv1["rate_hz"] == pytest.approx(4 / (16 * 0.02))
    assert conv1["dense_macs_per_step"] == 4 * 2 * 2 * 2 * 9
    assert readout["synops"] == 4 * 3
    assert readout["dense_macs_per_step"] == 16 * 3  # every layer-1 neuron to 3 outputs
    assert stats["synops_per_s"] == pytest.approx((20 + 12) / 0.02)
