"""Windows, encodings and batched prediction, checked on hand-built sequences."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from spikegyro.errors import InputError
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording
from spikegyro.train.data import (
    FileSource,
    InputSpec,
    TrainingSamples,
    encode_target,
    encode_window,
    fixed_windows,
    model_batch,
)
from spikegyro.train.infer import predict_windows

W, H = 32, 24


def omega_of(t_us: np.ndarray) -> np.ndarray:
    """A piecewise-linear-free ground truth: linear in time, so interpolation is exact."""
    t = np.asarray(t_us, dtype=np.float64)[..., None] / 1e6
    return np.concatenate([1.0 + t, -2.0 * t, 0.5 - t], axis=-1)


def make_sequence(duration_ms: int = 500, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    n = 4000
    t = np.sort(rng.integers(0, duration_ms * 1000, n))
    events = EventArray.from_arrays(
        rng.integers(0, W, n), rng.integers(0, H, n), t, rng.integers(0, 2, n), W, H
    )
    gyro_t = np.arange(0, duration_ms * 1000 + 1, 1000)
    return Recording(events, GyroTrace.from_arrays(gyro_t, omega_of(gyro_t)))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    for split, n in (("train", 2), ("val", 1), ("test", 2)):
        for i in range(n):
            write_recording(root / split / f"seq_{i:06d}.h5", make_sequence(seed=i))
    return root


def test_fixed_windows_tile_each_sequence_with_end_of_bin_labels(dataset):
    windows = fixed_windows(dataset, "test", 100)
    assert len(windows) == 10  # five per 500 ms sequence
    assert [w.index for w in windows[:5]] == [0, 1, 2, 3, 4]
    assert [w.t_start_us for w in windows[:5]] == [0, 100_000, 200_000, 300_000, 400_000]
    w = windows[2]
    ends = 200_000 + 1000 * np.arange(1, 101)
    np.testing.assert_allclose(w.omega, omega_of(ends), rtol=1e-6)
    np.testing.assert_allclose(w.omega_start, omega_of(np.array([200_000]))[0], rtol=1e-6)
    assert w.events.t.min() >= 200_000 and w.events.t.max() < 300_000
    rec = make_sequence(seed=0)
    expected = int(((rec.events.t >= 200_000) & (rec.events.t < 300_000)).sum())
    assert len(w.events) == expected


def test_missing_split_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match=r"no \.h5 sequence files"):
        fixed_windows(tmp_path, "test")


def test_spike_encoding_puts_each_event_in_its_millisecond_bin(dataset):
    w = fixed_windows(dataset, "val", 100)[1]
    spec = InputSpec(sensor=(W, H), window_ms=100)
    x = encode_window(w, spec)
    assert x.shape == (2, H, W, 100)
    for i in range(0, len(w.events), 97):
        k = (int(w.events.t[i]) - w.t_start_us) // 1000
        assert x[int(w.events.p[i]), int(w.events.y[i]), int(w.events.x[i]), k] == 1.0
    assert float(x.sum()) <= len(w.events)
    target = encode_target(w, spec)
    assert target.shape == (3, 100)
    np.testing.assert_allclose(target.numpy().T, w.omega)


def test_scale_halves_the_input_resolution(dataset):
    w = fixed_windows(dataset, "val", 100)[0]
    spec = InputSpec(sensor=(W, H), scale=0.5, window_ms=100)
    assert encode_window(w, spec).shape == (2, H // 2, W // 2, 100)
    with pytest.raises(InputError, match="expects 64x48"):
        encode_window(w, InputSpec(sensor=(64, 48), window_ms=100))


@pytest.mark.parametrize("representation", ["voxel", "frames"])
def test_ann_encodings_split_the_window_into_target_windows(dataset, representation):
    w = fixed_windows(dataset, "val", 100)[0]
    spec = InputSpec.for_representation(
        representation, sensor=(W, H), scale=1.0, window_ms=100, num_bins=5, target_ms=20
    )
    x = encode_window(w, spec)
    assert x.shape == (5, spec.in_channels, H, W)
    # each sub-window holds exactly its own events: the voxel grid preserves signed polarity sums
    if representation == "voxel":
        for j in range(5):
            sub = w.events.slice_time(20_000 * j, 20_000 * (j + 1))
            signed = (2.0 * sub.p.astype(np.float64) - 1).sum()
            assert float(x[j].sum()) == pytest.approx(signed, abs=1e-3)
    target = encode_target(w, spec)
    assert target.shape == (5, 3)
    np.testing.assert_allclose(target[1].numpy(), w.omega[20:40].mean(axis=0), rtol=1e-6)
    xb, tb = model_batch(x[None].repeat(2, 1, 1, 1, 1), target[None].repeat(2, 1, 1), spec)
    assert xb.shape == (10, spec.in_channels, H, W) and tb.shape == (10, 3)


class SumModel(nn.Module):
    """Deterministic stand-in whose outputs are easy to predict by hand."""

    def __init__(self, per_step: bool) -> None:
        super().__init__()
        self.per_step = per_step
        self.w = nn.Parameter(torch.ones(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.per_step:  # (N, 2, H, W, T) -> (N, 3, T): event count per bin on every axis
            return self.w * x.sum(dim=(1, 2, 3))[:, None, :].repeat(1, 3, 1)
        s = x.flatten(1).abs().sum(1)  # (N*S, C, H, W) -> (N*S, 3)
        return self.w * torch.stack([s, -s, 2 * s], dim=1)


class EngineModel(SumModel):
    """A model on the event-driven CPU engine: it records the layout of its inputs."""

    event_engine = "engine"

    def __init__(self, per_step: bool) -> None:
        super().__init__(per_step)
        self.layouts: list[torch.layout] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.layouts.append(x.layout)
        return super().forward(x.to_dense())


def test_predict_windows_per_step_and_held_window_means(dataset):
    windows = fixed_windows(dataset, "test", 100)[:3]
    spec = InputSpec(sensor=(W, H), window_ms=100)
    pred = predict_windows(SumModel(True), {"input": spec.as_dict()}, windows, batch_size=2)
    assert pred.shape == (3, 100, 3)
    expected = np.stack([encode_window(w, spec).sum(dim=(0, 1, 2)).numpy() for w in windows])
    np.testing.assert_allclose(pred[:, :, 0], expected)

    engine = EngineModel(True)  # an event-driven engine gets the same spikes, sparse
    assert np.array_equal(predict_windows(engine, spec, windows, batch_size=2), pred)
    assert engine.layouts == [torch.sparse_coo, torch.sparse_coo]

    ann = InputSpec.for_representation("frames", sensor=(W, H), scale=1.0, window_ms=100)
    pred = predict_windows(SumModel(False), ann.as_dict(), windows, batch_size=2)
    assert pred.shape == (3, 100, 3)
    for i, w in enumerate(windows):
        frames = encode_window(w, ann)
        for j in range(5):
            s = float(frames[j].abs().sum())
            np.testing.assert_allclose(pred[i, 20 * j : 20 * (j + 1)], [[s, -s, 2 * s]] * 20,
                                       rtol=1e-5)  # fmt: skip


def test_training_samples_are_a_pure_function_of_seed_and_index(dataset):
    spec = InputSpec(sensor=(W, H), window_ms=50)
    source = FileSource.from_split(dataset, "train", 50)
    a, b = TrainingSamples(source, spec, seed=3), TrainingSamples(source, spec, seed=3)
    starts = {a.window(i).t_start_us for i in range(20)}
    assert len(starts) > 5  # random starts
    assert all(s % 1000 == 0 and 0 <= s <= 450_000 for s in starts)
    for i in (0, 7):
        torch.testing.assert_close(a[i][0], b[i][0])
        torch.testing.assert_close(a[i][1], b[i][1])
    assert not torch.equal(a[0][1], TrainingSamples(source, spec, seed=4)[0][1])


def test_a_file_source_reads_the_window_that_the_whole_sequence_gives(dataset):
    """Training windows come from partial reads of their file: the same windows (events,
    labels) as cutting them out of the whole sequence with the same random draws."""
    from spikegyro.events.io import read_recording
    from spikegyro.train.data import random_window

    source = FileSource.from_split(dataset, "train", 50)
    for index in range(12):
        window = source.draw(np.random.default_rng([5, index]), index)
        rng = np.random.default_rng([5, index])
        path = source.files[int(rng.integers(len(source.files)))]
        whole = random_window(read_recording(path), 50, rng, source=path, index=index)
        assert (window.source, window.t_start_us) == (whole.source, whole.t_start_us)
        for name in ("x", "y", "t", "p"):
            np.testing.assert_array_equal(getattr(window.events, name), getattr(whole.events, name))
        np.testing.assert_array_equal(window.omega, whole.omega)
        np.testing.assert_array_equal(window.omega_start, whole.omega_start)
