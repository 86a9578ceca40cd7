"""Each augmentation against the simulator itself.

A flipped window must look like what the simulator produces for the mirrored world (mirrored
panorama, camera orientation M R M) moving with the augmentation's transformed angular velocity;
a time-reversed window like the simulation of the reversed trajectory. If a label sign were
wrong, the simulated motion would differ and the events would not match.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from spikegyro.events.core import EventArray
from spikegyro.sim.camera import Camera
from spikegyro.sim.esim import simulate
from spikegyro.sim.panorama import Panorama, mirror_panorama
from spikegyro.sim.sensor import EventSimConfig
from spikegyro.sim.trajectory import Trajectory, random_rotation
from spikegyro.train.augment import (
    HORIZONTAL_MIRROR,
    VERTICAL_MIRROR,
    AugmentConfig,
    add_noise_events,
    centre_mask,
    flip_horizontal,
    flip_vertical,
    keep_centre,
    mirror_omega,
    reverse_time,
    thin,
)
from spikegyro.train.data import InputSpec, Window, encode_window, window_at

WINDOW_MS = 40
# principal point at the pixel-grid centre: the image mirror x -> W-1-x is the world mirror
CAMERA = Camera(64, 48, fx=56.0, fy=56.0, cx=31.5, cy=23.5)
# deterministic thresholds, so that mirrored pixels fire alike
SENSOR = EventSimConfig(mismatch_std=0.0, noise_std=0.0)
SPEC = InputSpec(sensor=(CAMERA.width, CAMERA.height), window_ms=WINDOW_MS)


@pytest.fixture(scope="module")
def scene() -> Panorama:
    rng = np.random.default_rng(1)
    texture = gaussian_filter(rng.standard_normal((256, 512)), sigma=2.0, mode="wrap")
    return Panorama(np.exp(1.5 * texture / texture.std()), "noise")


@pytest.fixture(scope="module")
def trajectory() -> Trajectory:
    knots = np.array([0.0, 0.02, 0.04])
    omega = np.array([[1.5, -2.0, 2.5], [2.0, -1.0, 3.0], [1.0, -2.5, 2.0]])
    r0 = random_rotation(np.random.default_rng(2))
    return Trajectory(knots, omega, r0=r0, duration_s=WINDOW_MS / 1000)


def simulated_window(scene: Panorama, trajectory: Trajectory) -> Window:
    rec = simulate(scene, trajectory, CAMERA, SENSOR, np.random.default_rng(0))
    return window_at(rec, 0, WINDOW_MS, source="sim")


@pytest.fixture(scope="module")
def original(scene, trajectory) -> Window:
    return simulated_window(scene, trajectory)


def agreement(a: Window, b: Window) -> float:
    """Intersection over union of the binary spike tensors (1 = identical streams)."""
    sa, sb = encode_window(a, SPEC).bool(), encode_window(b, SPEC).bool()
    return float((sa & sb).sum() / (sa | sb).sum())


def mirrored_trajectory(trajectory: Trajectory, mirror: np.ndarray) -> Trajectory:
    """The world mirror built from geometry alone: orientation M R M, ω from the augmentation."""
    return Trajectory(
        trajectory.t_s,
        mirror_omega(trajectory.omega, mirror),
        r0=mirror @ trajectory.r0 @ mirror,
        duration_s=trajectory.duration_s,
    )


@pytest.mark.parametrize(
    ("flip", "mirror", "axis"),
    [(flip_horizontal, HORIZONTAL_MIRROR, 0), (flip_vertical, VERTICAL_MIRROR, 1)],
)
def test_flip_matches_the_simulated_mirror_world(scene, trajectory, original, flip, mirror, axis):
    augmented = flip(original)
    expected = simulated_window(
        mirror_panorama(scene, axis), mirrored_trajectory(trajectory, mirror)
    )
    assert len(original.events) > 2000
    assert agreement(augmented, expected) > 0.99
    # labels: the simulator's gyro of the mirrored motion, and the simulator's own derivation
    np.testing.assert_allclose(augmented.omega, expected.omega, atol=1e-6)
    np.testing.assert_allclose(
        augmented.omega, simulated_window(scene, trajectory.mirrored(axis)).omega, atol=1e-6
    )
    # the comparison can fail: the unflipped stream, or the right flip with the other label,
    # disagree with the mirrored simulation
    assert agreement(original, expected) < 0.2
    other = VERTICAL_MIRROR if axis == 0 else HORIZONTAL_MIRROR
    wrong = simulated_window(mirror_panorama(scene, axis), mirrored_trajectory(trajectory, other))
    assert agreement(augmented, wrong) < 0.2


def coarse_signed_counts(window: Window, block_ms: int = 5) -> np.ndarray:
    """ON minus OFF spikes per pixel (blurred by 1 px) in blocks of ``block_ms`` ms."""
    s = encode_window(window, SPEC).numpy()
    signed = s[1] - s[0]  # (H, W, T)
    blocks = signed.reshape(*signed.shape[:2], -1, block_ms).sum(-1)
    return gaussian_filter(blocks, sigma=(1.0, 1.0, 0))


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_time_reversal_matches_the_simulated_reversed_trajectory(scene, trajectory, original):
    augmented = reverse_time(original)
    expected = simulated_window(scene, trajectory.reversed())
    # labels: exactly the reversed motion's gyro at the end of each bin
    np.testing.assert_allclose(augmented.omega, expected.omega, atol=1e-6)
    np.testing.assert_allclose(augmented.omega_start, expected.omega_start, atol=1e-6)
    # events: the same brightness edges crossed backwards with swapped polarity. The reference
    # level of each pixel starts from the other end, so compare at 5 ms / 1 px resolution.
    a, b = coarse_signed_counts(augmented), coarse_signed_counts(expected)
    assert correlation(a, b) > 0.85
    # without the polarity swap (or without reversing) the streams anti- or de-correlate
    unswapped = replace(augmented, events=replace(augmented.events, p=1 - augmented.events.p))
    assert correlation(coarse_signed_counts(unswapped), b) < -0.5
    assert correlation(coarse_signed_counts(original), b) < 0.3


def test_double_application_is_identity(original):
    for op in (flip_horizontal, flip_vertical, reverse_time):
        twice = op(op(original))
        for name in ("x", "y", "t", "p"):
            np.testing.assert_array_equal(
                np.sort(getattr(twice.events, name)), np.sort(getattr(original.events, name))
            )
        np.testing.assert_allclose(twice.omega, original.omega)
        np.testing.assert_allclose(twice.omega_start, original.omega_start)


def test_random_augmentation_applies_each_transform_independently(original):
    ev = original.events
    signature = {
        "hflip": lambda w: np.array_equal(np.sort(w.events.x), np.sort(ev.width - 1 - ev.x)),
        "vflip": lambda w: np.array_equal(np.sort(w.events.y), np.sort(ev.height - 1 - ev.y)),
        "time_reverse": lambda w: int(w.events.p.sum()) == len(ev) - int(ev.p.sum()),
    }
    assert not any(sig(original) for sig in signature.values())
    rng = np.random.default_rng(0)
    draws = [AugmentConfig()(original, rng) for _ in range(200)]
    for sig in signature.values():
        assert 70 < sum(sig(w) for w in draws) < 130
    only_h = AugmentConfig(1.0, 0.0, 0.0)(original, rng)
    assert signature["hflip"](only_h) and not signature["time_reverse"](only_h)
    off = AugmentConfig(0.0, 0.0, 0.0)
    assert not off.enabled
    assert off(original, rng) is original


def _same_events(a: Window, b: Window) -> None:
    for name in ("x", "y", "t", "p"):
        np.testing.assert_array_equal(getattr(a.events, name), getattr(b.events, name))
    np.testing.assert_array_equal(a.omega, b.omega)


def test_event_drop_commutes_with_the_mirrors_and_time_inversion(original):
    keep = np.random.default_rng(3).random(len(original.events)) < 0.4
    for op in (flip_horizontal, flip_vertical):
        _same_events(thin(op(original), keep), op(thin(original, keep)))
    # Time inversion reverses the stream, so the same events are the reversed mask.
    _same_events(thin(reverse_time(original), keep[::-1]), reverse_time(thin(original, keep)))
    # Labels are untouched and the kept events are a subset in order.
    thinned = thin(original, keep)
    np.testing.assert_array_equal(thinned.omega, original.omega)
    np.testing.assert_array_equal(thinned.events.t, original.events.t[keep])


def test_event_drop_keeps_a_uniform_share_per_window_and_is_off_by_default(original):
    from scipy.stats import kstest

    n = len(original.events)
    config = AugmentConfig(0.0, 0.0, 0.0, keep_min=0.2)
    assert config.enabled and not AugmentConfig(0.0, 0.0, 0.0).enabled
    rng = np.random.default_rng(4)
    shares = np.array([len(config(original, rng).events) / n for _ in range(300)])
    # Per-window share ~ U(0.2, 1) (binomial spread at this n is below 0.01).
    assert kstest(shares, "uniform", args=(0.2, 0.8)).pvalue > 1e-3
    assert shares.min() >= 0.18 and shares.max() <= 1.0
    # The paper's augmentation draws exactly what it drew before density augmentation existed.
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    _same_events(AugmentConfig()(original, a), AugmentConfig(keep_min=1.0)(original, b))
    assert a.random() == b.random()


def test_noise_events_arrive_at_their_rate_inside_the_window(original):
    window = replace(original, events=original.events[:0])
    rng = np.random.default_rng(6)
    rate = 50.0
    counts = [len(add_noise_events(window, rate, rng).events) for _ in range(50)]
    expected = rate * CAMERA.width * CAMERA.height * WINDOW_MS / 1000
    assert abs(np.mean(counts) - expected) < 4 * np.sqrt(expected / 50)
    noisy = add_noise_events(original, rate, rng)
    ev = noisy.events
    ev.validate()
    assert ev.t.min() >= original.t_start_us and ev.t.max() < original.t_end_us
    added = len(ev) - len(original.events)
    assert (
        added > 1000 and abs((int(ev.p.sum()) - int(original.events.p.sum())) / added - 0.5) < 0.1
    )
    np.testing.assert_array_equal(noisy.omega, original.omega)
    # Through AugmentConfig the rate is U(0, noise_hz) per window: mean count half the maximum.
    config = AugmentConfig(0.0, 0.0, 0.0, noise_hz=rate)
    counts = [len(config(window, rng).events) for _ in range(200)]
    assert np.mean(counts) == pytest.approx(expected / 2, rel=0.15)


def test_presets_turn_density_augmentation_on_only_where_asked():
    from spikegyro.errors import InputError
    from spikegyro.train.presets import resolve_config

    paper = AugmentConfig.of(resolve_config("paper", {"data": "d"}))
    assert (paper.keep_min, paper.noise_hz) == (1.0, 0.0)
    sim2real = resolve_config("sim2real", {})
    assert sim2real.online and sim2real.sim == {"sensor": "davis240c"}
    assert AugmentConfig.of(sim2real).keep_min == 0.2
    assert AugmentConfig.of(sim2real).centre == 0.25 and paper.centre == 0.0
    flag = resolve_config("paper", {"data": "d", "event_keep_min": 0.5, "noise_events_hz": 2.0})
    assert AugmentConfig.of(flag) == AugmentConfig(keep_min=0.5, noise_hz=2.0)
    with pytest.raises(InputError, match="event-keep-min"):
        resolve_config("paper", {"data": "d", "event_keep_min": 1.5})
    with pytest.raises(InputError, match="centre-crop"):
        resolve_config("paper", {"data": "d", "centre_crop": -0.1})


def test_the_aperture_keeps_a_centred_box_and_commutes_with_the_mirrors(original):
    # One event on every pixel: the kept pixels are the box, counted by hand.
    ys, xs = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width]
    grid = EventArray.from_arrays(
        xs.ravel(), ys.ravel(), np.arange(xs.size), np.zeros(xs.size), CAMERA.width, CAMERA.height
    )
    kept = centre_mask(grid, 0.5).reshape(CAMERA.height, CAMERA.width)
    cols, rows = np.flatnonzero(kept.any(axis=0)), np.flatnonzero(kept.any(axis=1))
    assert (cols[0], cols[-1], rows[0], rows[-1]) == (16, 47, 12, 35)  # 32 x 24 of 64 x 48
    assert kept.sum() == 32 * 24 and kept[12:36, 16:48].all()
    assert centre_mask(grid, 1.0).all() and not centre_mask(grid, 0.0).any()
    for fraction in (0.3, 0.55):
        cropped = keep_centre(original, fraction)
        assert 0 < len(cropped.events) < len(original.events)
        np.testing.assert_array_equal(cropped.omega, original.omega)
        for op in (flip_horizontal, flip_vertical, reverse_time):
            _same_events(keep_centre(op(original), fraction), op(cropped))


def test_the_aperture_is_drawn_with_its_probability_and_off_by_default(original):
    n = len(original.events)
    config = AugmentConfig(0.0, 0.0, 0.0, centre=0.3)
    assert config.enabled
    rng = np.random.default_rng(7)
    shares = np.array([len(config(original, rng).events) / n for _ in range(400)])
    cropped = shares < 1.0
    assert cropped.mean() == pytest.approx(0.3, abs=0.07)
    # A box of side U(0.3, 0.7) keeps 9-49 % of the area; this texture fires evenly.
    assert shares[cropped].min() > 0.05 and shares[cropped].max() < 0.6
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    _same_events(AugmentConfig()(original, a), AugmentConfig(centre=0.0)(original, b))
    assert a.random() == b.random()
