"""ANN training targets: the mean ω over each 20 ms window, recomputed by hand from the gyro file.

The ground truth here is nonlinear and sampled off the millisecond grid (every 0.7 ms), so the
per-millisecond labels come from interpolation; the hand computation interpolates the raw samples
with ``np.interp`` itself. A label of bin k is ω at the bin's end, so a 20 ms target is the mean of
ω at a + 1 ms, ..., a + 20 ms.
"""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording
from spikegyro.train.augment import AugmentConfig
from spikegyro.train.data import (
    FileSource,
    InputSpec,
    TrainingSamples,
    encode_target,
    fixed_windows,
)

W, H = 64, 64
GYRO_STEP_US = 700
DURATION_MS = 300
TARGET_MS = 20


def omega_true(t_us: np.ndarray) -> np.ndarray:
    """A smooth, clearly nonlinear angular velocity, rad/s, shape (..., 3)."""
    t = np.asarray(t_us, dtype=np.float64)[..., None] / 1e6
    return np.concatenate(
        [3.0 * np.sin(40.0 * t), 2.0 * np.cos(25.0 * t) - 1.0, 4.0 * (t - 0.15) ** 2 - 0.5],
        axis=-1,
    )


GYRO_T = np.arange(0, DURATION_MS * 1000 + 1, GYRO_STEP_US)
GYRO_OMEGA = omega_true(GYRO_T)


def hand_window_means(t_start_us: int, num_windows: int) -> np.ndarray:
    """(num_windows, 3): mean of the interpolated ω at the 20 bin ends of each sub-window."""
    out = np.empty((num_windows, 3))
    for j in range(num_windows):
        ends = t_start_us + 1000 * (TARGET_MS * j + np.arange(1, TARGET_MS + 1))
        out[j] = [np.interp(ends, GYRO_T, GYRO_OMEGA[:, a]).mean() for a in range(3)]
    return out


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    rng = np.random.default_rng(7)
    n = 3000
    events = EventArray.from_arrays(
        rng.integers(0, W, n),
        rng.integers(0, H, n),
        np.sort(rng.integers(0, DURATION_MS * 1000, n)),
        rng.integers(0, 2, n),
        W,
        H,
    )
    root = tmp_path_factory.mktemp("targets")
    rec = Recording(events, GyroTrace.from_arrays(GYRO_T, GYRO_OMEGA))
    for split in ("train", "test"):
        write_recording(root / split / "seq_000000.h5", rec)
    return root


def ann_spec(representation: str = "voxel") -> InputSpec:
    return InputSpec.for_representation(
        representation, sensor=(W, H), scale=1.0, window_ms=100, num_bins=5, target_ms=TARGET_MS
    )


@pytest.mark.parametrize("representation", ["voxel", "frames"])
def test_fixed_window_targets_are_hand_computed_20ms_means(dataset, representation):
    windows = fixed_windows(dataset, "test", 100)
    assert [w.t_start_us for w in windows] == [0, 100_000]  # 300 ms GT span -> two full windows
    for w in windows:
        target = encode_target(w, ann_spec(representation)).numpy()
        assert target.shape == (5, 3)
        np.testing.assert_allclose(target, hand_window_means(w.t_start_us, 5), atol=1e-5)


def test_end_of_bin_mean_is_the_time_average_shifted_by_half_a_millisecond(dataset):
    """Independent closed form: against the continuous ω, the mean of the bin-end samples is
    the time average over [a + 0.5 ms, a + 20.5 ms] up to O(ω'' dt²) terms."""
    w = fixed_windows(dataset, "test", 100)[1]
    target = encode_target(w, ann_spec()).numpy()
    for j in range(5):
        a = w.t_start_us + 1000 * TARGET_MS * j
        fine = np.linspace(a + 500, a + 20_500, 20_001)
        continuous_mean = omega_true(fine).mean(axis=0)
        # |ω''| <= 4800 rad/s^3 here: linear interpolation of the 0.7 ms samples errs by at most
        # 4800 * 0.7e-3^2 / 8 = 3e-4, the midpoint rule by 4800 * 1e-3^2 / 24 = 2e-4 rad/s; labels
        # taken at bin starts instead of ends would be off by ~|ω'| * 1 ms ~ 0.1 rad/s.
        np.testing.assert_allclose(target[j], continuous_mean, atol=1e-3)


@pytest.mark.parametrize(
    ("augment", "transform"),
    [
        (AugmentConfig(0.0, 0.0, 0.0), np.array([1.0, 1.0, 1.0])),
        (AugmentConfig(1.0, 0.0, 0.0), np.array([1.0, -1.0, -1.0])),  # left-right mirror
        (AugmentConfig(0.0, 1.0, 0.0), np.array([-1.0, 1.0, -1.0])),  # up-down mirror
    ],
    ids=["plain", "hflip", "vflip"],
)
def test_random_training_window_targets(dataset, augment, transform):
    samples = TrainingSamples(
        FileSource.from_split(dataset, "train", 100), ann_spec(), seed=3, augment=augment
    )
    for index in range(4):
        start = samples.window(index).t_start_us
        assert start % 1000 == 0 and 0 <= start <= (DURATION_MS - 100) * 1000
        _, target = samples[index]
        np.testing.assert_allclose(
            target.numpy(), hand_window_means(start, 5) * transform, atol=1e-5
        )


def test_time_reversed_window_targets(dataset):
    """Played backwards, sub-window j covers the original [t1 - 20(j+1), t1 - 20j) ms with
    ω'(τ) = -ω(t1 - τ); its bin ends are the original times t1 - 20j - 1, ..., t1 - 20j - 20 ms."""
    samples = TrainingSamples(
        FileSource.from_split(dataset, "train", 100),
        ann_spec(),
        seed=5,
        augment=AugmentConfig(0.0, 0.0, 1.0),
    )
    for index in range(4):
        t1 = samples.window(index).t_end_us
        _, target = samples[index]
        expected = np.empty((5, 3))
        for j in range(5):
            times = t1 - 1000 * (TARGET_MS * j + np.arange(1, TARGET_MS + 1))
            expected[j] = [-np.interp(times, GYRO_T, GYRO_OMEGA[:, a]).mean() for a in range(3)]
        np.testing.assert_allclose(target.numpy(), expected, atol=1e-5)
