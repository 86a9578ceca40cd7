"""Event-list batches binned in one go must equal the one-window CPU encoders, bit for bit.

The reference is :func:`spikegyro.train.data.encode_window` (via
:mod:`spikegyro.events.representations`), applied window by window to the same (augmented,
rescaled) windows; the batch path sends flat event lists with a window index and bins them with
:mod:`spikegyro.events.binning_torch`. On the CPU both sum in the same order, so equality is
exact. On a GPU (when present) the spike tensors and frames must still be exact, the voxel grid
within float rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spikegyro.events import binning_torch
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.train.augment import AugmentConfig, flip_horizontal, flip_vertical, reverse_time
from spikegyro.train.data import (
    EventBatch,
    InputSpec,
    collate_events,
    device_batch,
    encode_batch,
    encode_target,
    encode_window,
    window_at,
    window_events,
)

W, H = 34, 26
WINDOW_MS = 40


def recording(seed: int, n: int) -> Recording:
    """Dense random events (many repeats per pixel and bin) with events on every 1 ms edge."""
    rng = np.random.default_rng(seed)
    edges = np.arange(0, 200_000, 1000)
    t = np.sort(np.concatenate([rng.integers(0, 200_000, n), edges, edges - 1][:-1]))
    t = t[t >= 0]
    m = t.size
    events = EventArray.from_arrays(
        rng.integers(0, W, m), rng.integers(0, H, m), t, rng.integers(0, 2, m), W, H
    )
    gyro_t = np.arange(0, 200_001, 1000)
    omega = np.stack([np.sin(gyro_t / 1e5), np.cos(gyro_t / 7e4), gyro_t / 2e5], axis=1)
    return Recording(events, GyroTrace.from_arrays(gyro_t, omega))


def windows() -> list:
    rec = recording(0, 6000)
    sparse = recording(1, 0)  # only the edge events
    out = [window_at(rec, 1000 * s, WINDOW_MS, source="r") for s in (0, 17, 130)]
    out.append(window_at(sparse, 5000, WINDOW_MS, source="s"))
    empty = out[0]
    out.append(type(empty)(EventArray.empty(W, H), 3000, empty.omega, empty.omega_start))
    return out


AUGMENTS = {
    "none": lambda w: w,
    "hflip": flip_horizontal,
    "vflip": flip_vertical,
    "reverse": reverse_time,
    "all": lambda w: reverse_time(flip_vertical(flip_horizontal(w))),
}


def device() -> str:
    return "cuda" if torch.cuda.is_available() else "cpu"


@pytest.mark.parametrize("scale", [1.0, 0.5])
@pytest.mark.parametrize("representation", ["spikes", "voxel", "frames"])
@pytest.mark.parametrize("augment", sorted(AUGMENTS))
def test_event_batch_encodes_exactly_like_the_dense_encoder(representation, scale, augment):
    spec = InputSpec.for_representation(
        representation, sensor=(W, H), scale=scale, window_ms=WINDOW_MS, num_bins=5, target_ms=10
    )
    batch_windows = [AUGMENTS[augment](w) for w in windows()]
    dense = torch.stack([encode_window(w, spec) for w in batch_windows])
    targets = torch.stack([encode_target(w, spec) for w in batch_windows])
    batch, stacked_targets = collate_events([(window_events(w, spec), encode_target(w, spec))
                                             for w in batch_windows])  # fmt: skip
    assert torch.equal(stacked_targets, targets)
    x, y = device_batch(batch, stacked_targets, spec, device())
    if representation == "spikes":
        assert x.shape == dense.shape
        assert dense.sum() > 0
    reference, reference_y = device_batch(dense, targets, spec, device())
    if representation == "voxel" and device() == "cuda":
        torch.testing.assert_close(x, reference, rtol=1e-6, atol=1e-6)
    else:
        assert torch.equal(x, reference)
    assert torch.equal(y, reference_y)
    if representation == "spikes":  # the event-driven CPU engine's input: a sparse tensor
        sparse, _ = device_batch(batch, stacked_targets, spec, "cpu", sparse=True)
        assert sparse.is_sparse and torch.equal(sparse.to_dense(), reference.cpu())


def test_event_lists_are_small_and_relative_to_the_window():
    spec = InputSpec(sensor=(W, H), window_ms=WINDOW_MS)
    w = windows()[1]
    one = window_events(w, spec)
    assert one.t.dtype == torch.int32 and one.x.dtype == torch.int16 and one.p.dtype == torch.uint8
    assert int(one.t.min()) >= 0 and int(one.t.max()) < WINDOW_MS * 1000
    assert int(one.counts[0]) == len(w.events)
    batch = EventBatch.concatenate([one, window_events(windows()[0], spec)])
    index = batch.window_index()
    assert index.tolist() == [0] * len(w.events) + [1] * len(windows()[0].events)


def test_spike_tensor_is_time_major_and_drops_events_outside_the_bins():
    # 3 windows of 2x3 px, 2 bins of 1 ms; the event at 2000 us and the one before 0 are dropped.
    x = torch.tensor([0, 2, 1, 1, 0])
    y = torch.tensor([0, 1, 1, 0, 1])
    t = torch.tensor([0, 1999, 2000, -1, 1000])
    p = torch.tensor([1, 0, 1, 1, 0])
    window = torch.tensor([0, 0, 1, 2, 2])
    out = binning_torch.spike_tensor(
        x, y, t, p, window, num_windows=3, height=2, width=3, num_bins=2
    )
    expected = torch.zeros(3, 2, 2, 3, 2)
    expected[0, 1, 0, 0, 0] = 1
    expected[0, 0, 1, 2, 1] = 1
    expected[2, 0, 1, 0, 1] = 1
    assert torch.equal(out, expected)
    assert out.permute(4, 0, 2, 3, 1).is_contiguous()  # (T, N, H, W, C) storage
    counted = binning_torch.spike_tensor(
        torch.tensor([1, 1]), torch.tensor([0, 0]), torch.tensor([0, 10]), torch.tensor([1, 1]),
        torch.tensor([0, 0]), num_windows=1, height=1, width=2, num_bins=1, count=True,
    )  # fmt: skip
    assert counted[0, 1, 0, 1, 0] == 2


@pytest.mark.parametrize("count", [False, True])
def test_a_sparse_spike_tensor_holds_the_dense_ones_entries_in_the_engines_order(count):
    """Events in any order, repeats, dropped ones: the same tensor as :func:`spike_tensor`, its
    entries stored by (window, step, pixel, channel), each once."""
    rng = np.random.default_rng(4)
    n, windows, height, width, bins = 5000, 3, 5, 7, 6
    x, y = torch.from_numpy(rng.integers(0, width, n)), torch.from_numpy(rng.integers(0, height, n))
    t, p = torch.from_numpy(rng.integers(-300, 6300, n)), torch.from_numpy(rng.integers(0, 2, n))
    window = torch.from_numpy(rng.integers(0, windows, n))
    shape = dict(num_windows=windows, height=height, width=width, num_bins=bins, count=count)
    dense = binning_torch.spike_tensor(x, y, t, p, window, **shape)
    sparse = binning_torch.spike_tensor(x, y, t, p, window, **shape, sparse=True)
    assert sparse.is_sparse and torch.equal(sparse.to_dense(), dense)
    n_, c, yy, xx, k = sparse._indices()
    key = (((n_ * bins + k) * height + yy) * width + xx) * 2 + c
    assert bool((key[1:] > key[:-1]).all())  # strictly increasing: sorted, no repeats
    assert sparse._nnz() == int((dense != 0).sum())


def test_random_augmentation_of_event_lists_matches_dense(monkeypatch):
    """The training samples' own augmentation, through both data paths."""
    from spikegyro.train.data import TrainingSamples

    class Source:
        def draw(self, rng, index):
            return window_at(recording(index, 3000), 1000 * int(rng.integers(0, 100)), WINDOW_MS)

    spec = InputSpec(sensor=(W, H), scale=0.5, window_ms=WINDOW_MS)
    kw = dict(seed=3, augment=AugmentConfig())
    dense = TrainingSamples(Source(), spec, **kw)
    events = TrainingSamples(Source(), spec, events=True, **kw)
    assert dense.collate is None and events.collate is collate_events
    indices = range(8)
    reference = torch.stack([dense[i][0] for i in indices])
    batch, _ = events.collate([events[i] for i in indices])
    assert torch.equal(encode_batch(batch, spec), reference)
