"""``spikegyro evaluate-real``: IMU-to-camera rotation, gyro window means, clock-offset fit, window
tiling, and the command end to end on a simulated recording written like a real one (ECD text
files, a gyro in its own axes at its own rate on a shifted clock)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from spikegyro.errors import InputError
from spikegyro.evaluate.offset import correlation, event_sample_times, fit_time_offset
from spikegyro.evaluate.real import parse_gyro_offset
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.imu import (
    imu_rotation,
    rotate_gyro,
    sampling_interval_us,
    shift_gyro,
    window_means,
)
from spikegyro.events.io import write_gyro_txt, write_recording
from spikegyro.events.windows import bin_means, event_windows, time_windows


@pytest.mark.parametrize(
    ("text", "imu", "camera"),
    [
        ("-x,-y,z", [1.0, 2.0, 3.0], [-1.0, -2.0, 3.0]),
        ("y x -z", [1.0, 2.0, 3.0], [2.0, 1.0, -3.0]),
        ("+z,x,y", [1.0, 2.0, 3.0], [3.0, 1.0, 2.0]),
        ("0,1,0, 1,0,0, 0,0,-1", [1.0, 2.0, 3.0], [2.0, 1.0, -3.0]),
    ],
)
def test_imu_to_camera_forms(text, imu, camera):
    rotation = imu_rotation(text)
    np.testing.assert_allclose(rotation @ imu, camera)
    trace = GyroTrace.from_arrays([0, 1000], [imu, imu])
    np.testing.assert_allclose(rotate_gyro(trace, rotation).omega, [camera, camera])


def test_imu_to_camera_matrix_from_scipy_rotation():
    rotation = Rotation.from_rotvec([0.3, -0.2, 1.1])
    text = ",".join(f"{v:.12f}" for v in rotation.as_matrix().ravel())
    w = np.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(imu_rotation(text) @ w, rotation.apply(w), atol=1e-9)


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("x,y,-z", "reflection"),
        ("x,x,z", "exactly once"),
        ("1,0,0,0,2,0,0,0,1", "orthonormal"),
        ("up,down,left", "signed axes"),
        ("1,0,0", "signed axes"),
    ],
)
def test_imu_to_camera_rejects(text, why):
    with pytest.raises(InputError, match=why):
        imu_rotation(text)


def test_window_means_equal_numerical_integrals():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.integers(300, 700, 40))
    omega = rng.normal(size=(40, 3))
    trace = GyroTrace.from_arrays(t, omega)
    starts = np.array([t[0], t[3] + 17.0, t[10] + 0.5, t[20]])
    ends = np.array([t[-1], t[4] - 3.0, t[30] + 123.0, t[20]])
    means = window_means(trace, starts, ends)
    for i, (a, b) in enumerate(zip(starts, ends, strict=True)):
        for k in range(3):
            if a == b:
                expected = np.interp(a, t, omega[:, k])
            else:
                points = t[(t > a) & (t < b)]
                area = quad(lambda s, k=k: np.interp(s, t, omega[:, k]), a, b, points=points,
                            limit=200)[0]  # fmt: skip
                expected = area / (b - a)
            assert means[i, k] == pytest.approx(expected, abs=1e-9)


def test_sampling_interval_and_shift():
    trace = GyroTrace.from_arrays([0, 400, 900, 1300], np.zeros((4, 3)))
    stats = sampling_interval_us(trace)
    assert stats["median_us"] == 400 and stats["min_us"] == 400 and stats["max_us"] == 500
    assert stats["rate_hz"] == pytest.approx(2500)
    np.testing.assert_array_equal(shift_gyro(trace, -250.4).t, [-250, 150, 650, 1050])
    with pytest.raises(InputError, match="fewer than two"):
        sampling_interval_us(GyroTrace.from_arrays([0], [[0, 0, 0]]))


def _wiggly_gyro(rate_hz: float = 200.0, seconds: float = 0.6, seed: int = 1) -> GyroTrace:
    """Sums of sinusoids (periods 40-200 ms), sampled at ``rate_hz`` from t = 0."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 1 / rate_hz)
    periods = rng.uniform(0.04, 0.2, (3, 3))
    phases = rng.uniform(0, 2 * np.pi, (3, 3))
    omega = np.stack(
        [np.sin(2 * np.pi * t[:, None] / periods[k] + phases[k]).sum(axis=1) for k in range(3)],
        axis=1,
    )
    return GyroTrace.from_arrays(np.rint(t * 1e6), omega)


@pytest.mark.parametrize("true_offset_us", [-7300.0, 0.0, 4100.0])
def test_offset_fit_recovers_an_injected_offset(true_offset_us):
    gyro = _wiggly_gyro()
    # Events denser in some places than others; estimates over 10 ms windows measure the
    # event-weighted mean omega on the events' clock, with a scale error, a bias and noise.
    # The gyro's clock runs `true_offset_us` behind (its stamps + offset = event time).
    rng = np.random.default_rng(2)
    events_t = np.sort(rng.choice(np.arange(0, 600_000), 40_000, p=_density(600_000)))
    ends = np.arange(100_000, 500_000, 5000)
    samples = event_sample_times(events_t, ends - 10_000, ends, count=64)
    truth = gyro.interpolate((samples - true_offset_us).ravel()).reshape(-1, 64, 3).mean(axis=1)
    estimates = 0.8 * truth + np.array([0.3, -0.2, 0.1]) + rng.normal(0, 0.05, truth.shape)
    fit = fit_time_offset(samples, estimates, gyro, max_offset_us=20_000, step_us=250)
    assert fit["offset_us"] == pytest.approx(true_offset_us, abs=150)
    assert not fit["at_edge"] and fit["correlation"] > 0.95
    assert fit["correlation"] >= fit["correlation_at_zero"]


def _density(n: int) -> np.ndarray:
    weight = 1.0 + 0.9 * np.sin(np.arange(n) / 7000.0)
    return weight / weight.sum()


def test_event_sample_times_follow_the_events():
    events_t = np.array([0, 1, 2, 3, 10, 20, 30, 40])
    samples = event_sample_times(events_t, np.array([0, 0, 50]), np.array([4, 41, 60]), count=4)
    np.testing.assert_array_equal(samples[0], [0, 1, 2, 3])
    np.testing.assert_array_equal(samples[1], [1, 3, 20, 40])  # indices 1, 3, 5, 7 of 8
    assert np.isnan(samples[2]).all()  # no events in [50, 60)


def test_offset_fit_declines_without_data_or_variation():
    gyro = _wiggly_gyro(seconds=0.1)
    samples = np.array([[45_000.0, 50_000.0], [50_000.0, 55_000.0]])
    fit = fit_time_offset(samples, np.zeros((2, 3)), gyro)
    assert fit["offset_us"] is None and "estimates" in fit["reason"]
    flat = GyroTrace.from_arrays([0, 1_000_000], np.ones((2, 3)))
    ends = np.arange(100_000, 900_000, 5000.0)
    fit = fit_time_offset(np.column_stack([ends - 10_000, ends]), np.ones((len(ends), 3)), flat)
    assert fit["offset_us"] is None and "unobservable" in fit["reason"]
    assert np.isnan(correlation(np.ones((5, 3)), np.ones((5, 3))))


def test_windows_by_time_and_by_events():
    starts, ends = time_windows(1000, 10_500, 2500.0)
    np.testing.assert_array_equal(starts, [1000, 3500, 6000])
    np.testing.assert_array_equal(ends, [3500, 6000, 8500])
    t = np.array([0, 5, 10, 10, 20, 30, 40, 50, 60, 70])
    starts, ends = event_windows(t, 10, 70, 3)
    np.testing.assert_array_equal(starts, [10, 30])  # events 2-4 and 5-7; 8 is left over
    np.testing.assert_array_equal(ends, [21, 51])


def test_bin_means_against_brute_force():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(12, 3))
    t0 = 5000
    per_us = np.repeat(values, 1000, axis=0)  # the series held over each 1 ms bin
    starts = np.array([5000, 6300, 9999, 12_000])
    ends = np.array([17_000, 6800, 14_001, 12_001])
    expected = [per_us[a - t0 : b - t0].mean(axis=0) for a, b in zip(starts, ends, strict=True)]
    np.testing.assert_allclose(bin_means(values, t0, starts, ends), expected, atol=1e-12)


def test_gyro_offset_option():
    assert parse_gyro_offset("auto") is None and parse_gyro_offset("-2.5") == -2.5
    with pytest.raises(InputError, match="--gyro-offset"):
        parse_gyro_offset("soon")


# --- end to end on a simulated recording -------------------------------------------------------

TRUE_OFFSET_MS = 4.0
ROTATION = "y,x,-z"  # omega_cam = (gy, gx, -gz)


def _omega_cam(t_s: np.ndarray) -> np.ndarray:
    """A fast, changing rotation (rad/s): every axis swings by 100+ deg/s within 100 ms."""
    t = np.asarray(t_s)[..., None]
    amp = np.radians([150.0, 120.0, 180.0])
    return amp * np.sin(2 * np.pi * t / np.array([0.11, 0.09, 0.13]) + np.array([0.3, 1.9, 4.0]))


@pytest.fixture(scope="module")
def real_like(tmp_path_factory):
    import spikegyro.sim as sim
    from spikegyro.sim.procedural import panorama_width, procedural_panorama

    root = tmp_path_factory.mktemp("real")
    camera = sim.Camera()
    panorama = procedural_panorama(np.random.default_rng(10), panorama_width(camera))
    knots = np.arange(0.0, 0.1601, 0.0005)
    trajectory = sim.Trajectory(knots, _omega_cam(knots), duration_s=0.16)
    rec = sim.simulate(panorama, trajectory, camera, sim.EventSimConfig(),
                       np.random.default_rng(0))  # fmt: skip
    # Events as a real camera's: t from 10 s on, text, its own calib.txt (the sim's pinhole).
    base_us = 10_000_000
    events = rec.events.shift_time(base_us)
    folder = write_recording(root / "cam", Recording(events=events))
    (folder / "calib.txt").write_text("200 200 120 90 0 0 0 0 0\n")
    # An IMU at 400 Hz in its own axes, stamped TRUE_OFFSET_MS early on its own clock.
    t_imu = np.arange(-0.05, 0.21, 0.0025)
    omega_imu = _omega_cam(t_imu) @ imu_rotation(ROTATION)  # R^T omega_cam, row-wise
    stamps = base_us + np.rint(t_imu * 1e6) - TRUE_OFFSET_MS * 1000
    imu = np.column_stack([stamps / 1e6, np.zeros((len(t_imu), 3)), omega_imu])
    np.savetxt(root / "imu.txt", imu, fmt="%.6f")
    out = root / "report"
    proc = subprocess.run(
        [sys.executable, "-m", "spikegyro", "evaluate-real", str(folder), "--gyro",
         str(root / "imu.txt"), "--imu-to-camera", ROTATION, "--gyro-offset", "auto",
         "--windows-ms", "10", "--max-offset-ms", "10", "--out", str(out)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    return out, metrics, base_us, proc.stderr


def _csv(path):
    names = path.read_text().splitlines()[0].split(",")
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {name: table[:, i] for i, name in enumerate(names)}


def test_e2e_outputs(real_like):
    out, metrics, _, stderr = real_like
    for name in ("report.html", "report.md", "predictions.csv", "windows.csv", "traces.png",
                 "offset.png", "bins.png", "axes_snn.png", "axes_cmax.png"):  # fmt: skip
        assert (out / name).stat().st_size > 0, name
    assert set(metrics["models"]) == {"SNN-6", "CMax", "CMax (live)", "Mean", "CMax (window)"}
    assert metrics["gyro"]["sampling_interval"]["median_us"] == pytest.approx(2500, abs=1)
    page = (out / "report.html").read_text()
    assert "Best clock offset" in page and "2.500 ms" in page
    assert "best clock offset" in stderr


def test_e2e_recovers_the_clock_offset_and_applies_the_rotation(real_like):
    out, metrics, base_us, _ = real_like
    fit = metrics["gyro"]["offset_fit"]
    assert fit["offset_us"] == pytest.approx(TRUE_OFFSET_MS * 1000, abs=1000), fit["offset_us"]
    assert metrics["gyro"]["offset_applied_us"] == fit["offset_us"]
    np.testing.assert_allclose(metrics["gyro"]["imu_to_camera"], imu_rotation(ROTATION))
    pred = _csv(out / "predictions.csv")
    gyro = np.column_stack([pred["gyro_wx"], pred["gyro_wy"], pred["gyro_wz"]])
    truth = _omega_cam(pred["t"] - base_us / 1e6)
    # Within what the fitted offset's error allows (|d omega/dt| < 13,000 deg/s^2 here).
    assert np.degrees(np.abs(gyro - truth)).max() < 15.0
    assert np.degrees(np.abs(gyro[:, 0] - truth[:, 1])).max() > 100.0  # axes really swapped


def _summary(pred: np.ndarray, gt: np.ndarray) -> dict:
    """The metrics, computed here from their definitions (docs/evaluation.md), deg/s."""
    err = np.degrees(np.linalg.norm(pred - gt, axis=1))
    speed = np.degrees(np.linalg.norm(gt, axis=1))
    keep = speed >= 1.0
    return {
        "median_relative_error": float(np.median(err[keep] / speed[keep])),
        "mean_euclidean_error_deg_s": float(err.mean()),
        "rmse_deg_s": float(np.sqrt((err**2).mean())),
        "mae": np.degrees(np.abs(pred - gt)).mean(axis=0),
    }


def test_e2e_metrics_equal_an_independent_computation(real_like):
    out, metrics, _, _ = real_like
    pred = _csv(out / "predictions.csv")
    scored = pred["scored"] == 1
    t0 = metrics["data"]["t0_s"]
    assert scored.sum() == metrics["data"]["scored_steps"]
    assert np.all(pred["t"][scored] - t0 > 0.050 - 1e-9) and not scored[:50].any()
    gt = np.column_stack([pred[f"gyro_{a}"] for a in ("wx", "wy", "wz")])[scored]
    windows = _csv(out / "windows.csv")
    w_gt = np.column_stack([windows[f"gyro_{a}"] for a in ("wx", "wy", "wz")])
    for name, key in (("SNN-6", "snn"), ("CMax", "cmax"), ("Mean", "mean")):
        series = np.column_stack([pred[f"{key}_{a}"] for a in ("wx", "wy", "wz")])[scored]
        mine = _summary(series, gt)
        theirs = metrics["models"][name]["metrics"]
        for k in ("median_relative_error", "mean_euclidean_error_deg_s", "rmse_deg_s"):
            assert theirs[k] == pytest.approx(mine[k], rel=1e-6), (name, k)
        for i, axis in enumerate(("tilt", "pan", "roll")):
            got = theirs["per_axis"][axis]["mean_abs_error_deg_s"]
            assert got == pytest.approx(mine["mae"][i], rel=1e-6)
        # per window: the mean of the per-ms series over each 10 ms window vs the gyro's mean
        full = np.column_stack([pred[f"{key}_{a}"] for a in ("wx", "wy", "wz")])
        step = np.rint((pred["t"] - t0) * 1000).astype(int)  # step k ends at k + 1 ms
        means = [full[(step > round((a - t0) * 1000)) & (step <= round((b - t0) * 1000))].mean(0)
                 for a, b in zip(windows["start"], windows["end"], strict=True)]  # fmt: skip
        win = _summary(np.array(means), w_gt)
        got = metrics["models"][name]["window_metrics"]
        assert got["mean_euclidean_error_deg_s"] == pytest.approx(
            win["mean_euclidean_error_deg_s"], rel=1e-6
        )
    assert metrics["data"]["windows"]["count"] == (metrics["data"]["steps_ms"] - 50) // 10
    # On simulated events, CMax from whole windows is far better than the mean predictor.
    cmax_w = metrics["models"]["CMax (window)"]["window_metrics"]
    mean_w = metrics["models"]["Mean"]["window_metrics"]
    assert cmax_w["mean_euclidean_error_deg_s"] < 0.35 * mean_w["mean_euclidean_error_deg_s"]


def _main(monkeypatch, capsys, *args):
    from spikegyro import cli

    monkeypatch.setattr(sys, "argv", ["spikegyro", "evaluate-real", *map(str, args)])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    err = capsys.readouterr().err
    return exit_info.value.code, err


def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 120_000, 3000))
    events = EventArray.from_arrays(rng.integers(0, 240, 3000), rng.integers(0, 180, 3000), t,
                                    rng.integers(0, 2, 3000), 240, 180)  # fmt: skip
    rec = write_recording(tmp_path / "rec.txt", Recording(events=events))
    gyro = tmp_path / "gyro.txt"
    write_gyro_txt(gyro, GyroTrace.from_arrays([0, 200_000], np.zeros((2, 3))))
    late = tmp_path / "late_gyro.txt"
    write_gyro_txt(late, GyroTrace.from_arrays([5_000_000, 6_000_000], np.zeros((2, 3))))
    out = tmp_path / "out"
    cases = [
        ((rec, "--out", out), "no gyro"),
        ((rec, "--gyro", tmp_path / "nope.txt", "--out", out), "nope.txt"),
        ((rec, "--gyro", gyro, "--imu-to-camera", "x,y,-z", "--out", out), "reflection"),
        ((rec, "--gyro", gyro, "--windows-ms", 10, "--windows-events", 5, "--out", out), "one of"),
        ((rec, "--gyro", gyro, "--windows-ms", 100, "--out", out), "no whole window"),
        ((rec, "--gyro", gyro, "--gyro-offset", "later", "--out", out), "--gyro-offset"),
        ((rec, "--gyro", late, "--out", out), "does not cover"),
    ]
    for args, needle in cases:
        code, err = _main(monkeypatch, capsys, *args)
        assert code == 2, (args, err)
        assert err.startswith("error:") and err.strip().count("\n") == 0, err
        assert needle in err, (needle, err)
    assert not out.exists() or not (out / "metrics.json").exists()
