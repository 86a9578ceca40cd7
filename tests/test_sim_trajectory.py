"""Random-rotation statistics and trajectory round trips."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.sim import Trajectory, random_trajectory, so3_exp, so3_log
from spikegyro.sim.trajectory import TrajectoryConfig, flip_trajectory


def test_random_omega_is_zero_mean_equally_spread_uncorrelated_with_a_fast_tail():
    n = 4000
    w = np.degrees(
        np.stack(
            [random_trajectory(np.random.default_rng(s), 0.05).omega_at(0.0) for s in range(n)]
        )
    )
    std = w.std(axis=0)
    # Zero mean per axis (within 4 standard errors).
    assert (np.abs(w.mean(axis=0)) < 4 * std / np.sqrt(n)).all()
    # Equal spread: per-axis standard deviations within 8% of each other.
    assert std.max() / std.min() < 1.08
    # Uncorrelated axes.
    corr = np.corrcoef(w.T)
    assert np.abs(corr[np.triu_indices(3, 1)]).max() < 0.06
    # Mean speed near the paper's mean-predictor error (226.9 deg/s), with a tail past 800.
    speed = np.linalg.norm(w, axis=1)
    assert 205 < speed.mean() < 245
    assert (speed > 800).sum() >= 1


def test_random_omega_varies_slightly_and_smoothly_within_a_sequence():
    rng = np.random.default_rng(0)
    t = np.arange(0, 0.501, 0.001)
    changes, jumps = [], []
    for _ in range(50):
        w = np.degrees(random_trajectory(rng, 0.5).omega_at(t))
        changes.append(np.abs(w[-1] - w[0]).max())
        jumps.append(np.abs(np.diff(w, axis=0)).max())
    # Within 500 ms ω drifts by tens of deg/s, not hundreds; no step larger than 1 deg/s per ms.
    assert 5 < np.median(changes) < 80
    assert max(jumps) < 1.0


def test_gyro_samples_are_1khz_inclusive_and_match_omega_at():
    traj = random_trajectory(np.random.default_rng(2), 0.5)
    t_us, omega = traj.gyro()
    assert t_us[0] == 0 and t_us[-1] == 500_000 and len(t_us) == 501
    assert (np.diff(t_us) == 1000).all()
    np.testing.assert_allclose(omega[123], traj.omega_at(0.123))


def test_arbitrary_samples_interpolate_linearly_and_rotation_composes():
    t = np.array([0.0, 0.1, 0.2])
    w = np.array([[0.0, 1.0, 0.0], [0.0, 3.0, 0.0], [0.0, 3.0, 0.0]])
    traj = Trajectory(t, w, duration_s=0.2)
    np.testing.assert_allclose(traj.omega_at(0.05), [0.0, 2.0, 0.0])
    # About one fixed axis, the angle is the integral of ω: 0.2 over [0, 0.1] + 0.3 over the rest.
    angle = so3_log(traj.rotation_at(0.2))
    np.testing.assert_allclose(angle, [0.0, 0.2 + 0.3, 0.0], atol=1e-9)
    np.testing.assert_allclose(so3_exp(so3_log(traj.rotation_at(0.13))), traj.rotation_at(0.13))


def test_slow_rotations_span_their_speed_range_on_every_axis_equally():
    from spikegyro.sim.trajectory import TrajectoryConfig

    config = TrajectoryConfig(slow_share=1.0, slow_min_deg=5.0, slow_max_deg=100.0)
    rng = np.random.default_rng(3)
    start = np.degrees([random_trajectory(rng, 0.1, config).omega[0] for _ in range(4000)])
    speed = np.linalg.norm(start, axis=1)
    assert speed.min() >= 5.0 - 1e-9 and speed.max() <= 100.0 + 1e-9
    # log-uniform: as many sequences below the geometric middle (22.4 deg/s) as above it
    assert abs(np.mean(speed < np.sqrt(5.0 * 100.0)) - 0.5) < 0.03
    # isotropic axis: each axis carries a third of the squared speed, roll included
    share = (start**2).sum(0) / (speed**2).sum()
    np.testing.assert_allclose(share, 1 / 3, atol=0.03)


def test_slow_share_mixes_the_two_motions_and_zero_draws_nothing_more():
    from spikegyro.sim.trajectory import TrajectoryConfig

    paper = [random_trajectory(np.random.default_rng(s), 0.1).omega for s in range(5)]
    same = [
        random_trajectory(np.random.default_rng(s), 0.1, TrajectoryConfig(slow_share=0.0)).omega
        for s in range(5)
    ]
    for a, b in zip(paper, same, strict=True):
        np.testing.assert_array_equal(a, b)
    mixed = TrajectoryConfig(slow_share=0.3)
    rng = np.random.default_rng(4)
    speeds = [
        np.degrees(np.linalg.norm(random_trajectory(rng, 0.1, mixed).omega[0])) for _ in range(3000)
    ]
    # paper motion falls below 100 deg/s in about 16 % of sequences: 0.3 + 0.7 * 0.16 = 0.41
    assert abs(np.mean(np.asarray(speeds) <= 100.0) - 0.41) < 0.04


def test_slow_rotation_drifts_by_its_stated_share_per_second():
    from spikegyro.sim.trajectory import TrajectoryConfig

    config = TrajectoryConfig(slow_share=1.0, slow_accel_per_s=0.5)
    rng = np.random.default_rng(5)
    ratios = []
    for _ in range(400):
        traj = random_trajectory(rng, 0.5, config)
        w0 = np.linalg.norm(traj.omega[0])
        ratios.append(np.linalg.norm(traj.omega[-1] - traj.omega[0]) / w0)
    # the acceleration, N(0, (0.5 |w0|)^2) per axis at knots 0.1 s apart and linear between,
    # changes w by a fraction of itself of order 0.5 * 0.5 s: never more than a few times that
    assert 0.05 < np.median(ratios) < 0.5


def test_a_flip_rolls_exactly_its_angle_peaking_at_twice_its_mean_rate():
    config = TrajectoryConfig(kind="flip", flip_deg=360.0, flip_ms=600.0)
    traj = flip_trajectory(0.8, config, drift=None)
    t = np.linspace(0.0, 0.8, 80_001)
    roll = np.degrees(traj.omega_at(t)[:, 2])
    # The integral against the closed form (360 deg), on a grid much finer than the knots.
    assert abs(np.trapezoid(roll, t) - 360.0) < 1e-3
    assert abs(roll.max() - 1200.0) < 0.1 and abs(t[roll.argmax()] - 0.4) < 1e-3
    assert roll[t < 0.1].max() < 1e-9 and roll[t > 0.7].max() < 1e-9  # centred, still outside
    # The orientation, integrated independently of the rate's integral: half a turn at the
    # middle, a whole turn (back where it started) at the end.
    assert np.allclose(traj.rotation_at(0.4), np.diag([-1.0, -1.0, 1.0]), atol=1e-3)
    assert np.abs(so3_log(traj.rotation_at(0.8))).max() < 1e-3


def test_random_flips_draw_only_the_drift_and_the_start_orientation():
    config = TrajectoryConfig(kind="flip", flip_drift_deg=10.0)
    t = np.linspace(0.0, 1.0, 1001)
    drifts = []
    for seed in range(200):
        w = np.degrees(random_trajectory(np.random.default_rng(seed), 1.0, config).omega_at(t))
        assert abs(np.trapezoid(w[:, 2], t) - 360.0) < 0.01
        assert np.ptp(w[:, :2], axis=0).max() < 1e-9  # constant tilt and pan
        drifts.append(w[0, :2])
    assert 8.0 < np.std(drifts) < 12.0
    with pytest.raises(ValueError, match="at least that long"):
        random_trajectory(np.random.default_rng(0), 0.5, config)
    with pytest.raises(ValueError, match="must be one of"):
        TrajectoryConfig(kind="loop").validate()
