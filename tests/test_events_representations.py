"""Input representations checked against hand computations and conservation laws."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikegyro.events.representations import accumulated_frames, spike_tensor, voxel_grid


def test_spike_tensor_bin_edges_are_half_open() -> None:
    # Bin k = [k, k+1) ms from t_start: 999 us -> bin 0, 1000 us -> bin 1, 2999 -> bin 2.
    x = np.array([1, 1, 2, 3, 0])
    y = np.array([0, 0, 1, 2, 0])
    t = np.array([10_000, 10_999, 11_000, 12_999, 13_000]) - 0
    p = np.array([1, 1, 0, 1, 1])
    out = spike_tensor(x, y, t, p, height=3, width=4, t_start_us=10_000, num_bins=3)
    assert out.shape == (2, 3, 4, 3)
    expected = np.zeros((2, 3, 4, 3), np.float32)
    expected[1, 0, 1, 0] = 1  # two events, binary
    expected[0, 1, 2, 1] = 1
    expected[1, 2, 3, 2] = 1  # event at 13_000 is bin 3: outside, dropped
    np.testing.assert_array_equal(out, expected)


def test_spike_tensor_count_mode_counts() -> None:
    out = spike_tensor(
        np.array([1, 1]),
        np.array([0, 0]),
        np.array([0, 500]),
        np.array([1, 1]),
        height=2,
        width=2,
        t_start_us=0,
        num_bins=1,
        count=True,
    )
    assert out[1, 0, 1, 0] == 2


def test_spike_tensor_torch_in_torch_out() -> None:
    args = [torch.tensor(v) for v in ([0], [1], [1500], [0])]
    out = spike_tensor(*args, height=2, width=2, t_start_us=0, num_bins=2)
    assert isinstance(out, torch.Tensor) and out[0, 1, 0, 1] == 1


def test_voxel_grid_hand_computed_case() -> None:
    # B = 3 over [0, 100] us: t* = 2 t / 100.
    x = np.array([0, 1, 1, 0])
    y = np.array([0, 0, 0, 0])
    t = np.array([0, 25, 50, 100])
    p = np.array([1, 0, 1, 1])
    grid = voxel_grid(x, y, t, p, height=1, width=2, num_bins=3)
    expected = np.zeros((3, 1, 2), np.float32)
    expected[0, 0, 0] += 1.0  # t* = 0
    expected[0, 0, 1] += -0.5  # t* = 0.5, OFF
    expected[1, 0, 1] += -0.5
    expected[1, 0, 1] += 1.0  # t* = 1.0, ON, all in bin 1
    expected[2, 0, 0] += 1.0  # t* = 2: last bin
    np.testing.assert_allclose(grid, expected, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.integers(0, 10_000), min_size=1, max_size=60),
    st.integers(2, 9),
    st.integers(0, 2**31 - 1),
)
def test_voxel_grid_conserves_weight_and_is_local(times: list[int], bins: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.sort(np.array(times))
    n = t.size
    x = np.arange(n) % 7  # distinct pixel per event (width 7 x height 9 > 60)
    y = np.arange(n) // 7
    p = rng.integers(0, 2, n)
    grid = voxel_grid(x, y, t, p, height=9, width=7, num_bins=bins)
    # Each event sits alone at its pixel: its total |weight| is 1 and lies in the two bins
    # around t* only.
    np.testing.assert_allclose(np.abs(grid).sum(), n, rtol=1e-5)
    span = max(t[-1] - t[0], 1e-9)
    for i in range(n):
        column = grid[:, y[i], x[i]]
        tstar = (bins - 1) * (t[i] - t[0]) / span
        allowed = {int(np.floor(tstar)), min(int(np.floor(tstar)) + 1, bins - 1)}
        nonzero = set(np.flatnonzero(np.abs(column) > 1e-7).tolist())
        assert nonzero <= allowed
        assert np.sign(column.sum()) == (1 if p[i] else -1)
        np.testing.assert_allclose(np.abs(column).sum(), 1.0, rtol=1e-5)


def test_frames_are_clipped_at_percentile_and_normalised() -> None:
    # 99 pixels with one ON event, one hot pixel with 1000 ON events, one OFF pixel with 2.
    x = np.concatenate([np.arange(99), np.full(1000, 99), [0, 0]])
    y = np.zeros_like(x)
    p = np.concatenate([np.ones(1099, int), [0, 0]])
    frames = accumulated_frames(x, y, p, height=1, width=100, percentile=50)
    # Non-zero counts: 99 ones, one 2, one 1000 -> median 1: everything saturates at 1.
    assert frames.shape == (2, 1, 100)
    assert frames.max() == pytest.approx(1.0)
    assert frames[1, 0, 99] == pytest.approx(1.0)
    assert frames[0, 0, 0] == pytest.approx(1.0)
    frames99 = accumulated_frames(x, y, p, height=1, width=100, percentile=99)
    scale = np.quantile(np.array([1] * 99 + [2, 1000], float), 0.99)
    assert frames99[1, 0, 5] == pytest.approx(1 / scale, rel=1e-5)
    assert frames99[1, 0, 99] == pytest.approx(1.0)


def test_frames_of_no_events_are_zero() -> None:
    empty = np.array([], dtype=np.int64)
    frames = accumulated_frames(empty, empty, empty, height=2, width=3)
    assert frames.shape == (2, 2, 3) and not frames.any()


def test_voxel_grids_of_consecutive_spans_equal_one_voxel_grid_per_span():
    """The one-pass NumPy kernel against the torch formula span by span, to the bit: events on
    span boundaries, at a span's last microsecond, before the first span and after the last."""
    from spikegyro.events.representations import voxel_grids

    rng = np.random.default_rng(3)
    n, span, start = 5000, 20_000, 1_000_000
    edges = start + span * np.arange(6)
    t = np.sort(np.concatenate([rng.integers(start - 500, edges[-1] + 500, n), edges, edges - 1]))
    x, y = rng.integers(0, 24, t.size), rng.integers(0, 16, t.size)
    p = rng.integers(0, 2, t.size)
    grids = voxel_grids(x, y, t, p, height=16, width=24, num_bins=5, t_start_us=start,
                        span_us=span, count=5)  # fmt: skip
    for j in range(5):
        a = start + j * span
        inside = (t >= a) & (t < a + span)
        expected = voxel_grid(x[inside], y[inside], t[inside], p[inside], height=16, width=24,
                              num_bins=5, t_start_us=a, t_end_us=a + span)  # fmt: skip
        np.testing.assert_array_equal(grids[j], expected)
    assert float(grids.sum()) == pytest.approx(
        float((2 * p - 1)[(t >= start) & (t < start + 5 * span)].sum()), abs=1e-2
    )
