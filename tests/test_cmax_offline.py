"""The offline engine: estimates at their own times from centred windows, one for a recording
shorter than the output period, and `predict --method cmax --offline` end to end."""

from __future__ import annotations

import numpy as np
import pytest
from test_cmax import HEIGHT, WIDTH, F, assert_close_omega, point_track_events
from typer.testing import CliRunner

from spikegyro.cli import app
from spikegyro.cmax.offline import estimate_offline, offline_times, predict_windows_offline
from spikegyro.events.calib import PinholeCamera

CAMERA = PinholeCamera(WIDTH, HEIGHT, F, F, WIDTH / 2, HEIGHT / 2)


def test_offline_times_are_the_output_clock_within_the_span_or_its_middle():
    assert offline_times(0, 35_000, 0, 100.0).tolist() == [10_000, 20_000, 30_000]
    assert offline_times(1_000, 6_500, 0, 100.0).tolist() == [3_750]


@pytest.mark.parametrize("omega_dps", [(0.0, 60.0, 0.0), (20.0, -30.0, 80.0)])
def test_offline_estimates_stand_for_their_own_time(omega_dps):
    omega = np.radians(omega_dps)
    events = point_track_events(omega, seed=2, duration_s=0.3, points=3000)
    est = estimate_offline(events, CAMERA)
    assert len(est) == 29 and (np.diff(est.t_us) == 10_000).all()
    inside = (est.t_us > 80_000) & (est.t_us < 220_000)  # windows not cut by the ends
    # Centred windows: the events' mean time within a tenth of the window of the estimate's
    # time (a causal window's lies half a window before it).
    assert (np.abs(est.delay_us[inside]) < 0.1 * est.window_us[inside]).all()
    for w in est.omega:
        assert_close_omega(w, omega)


def test_a_recording_shorter_than_the_period_gets_one_offline_estimate():
    omega = np.radians([0.0, 0.0, 400.0])
    events = point_track_events(omega, seed=11, duration_s=0.006, points=3000)
    est = estimate_offline(events, CAMERA)
    assert len(est) == 1
    assert_close_omega(est.omega[0], omega)


def test_predict_offline_and_its_bad_combinations(tmp_path):
    from spikegyro.events.core import Recording
    from spikegyro.events.io import write_recording

    path = tmp_path / "pan.h5"
    events = point_track_events(np.radians([0.0, 60.0, 0.0]), seed=4, duration_s=0.1, points=3000)
    write_recording(path, Recording(events, None, {"fx": F, "fy": F, "cx": 120.0, "cy": 90.0}))
    out = tmp_path / "off.csv"
    done = CliRunner().invoke(
        app, ["predict", str(path), "--method", "cmax", "--offline", "--out", str(out)]
    )
    assert done.exit_code == 0, done.output
    assert "offline" in done.output and out.exists()
    for extra in (["--method", "snn"], ["--method", "cmax", "--window-ms", "20"]):
        bad = CliRunner().invoke(app, ["predict", str(path), *extra, "--offline", "-o", "x.csv"])
        assert bad.exit_code != 0 and "--offline" in str(bad.exception)


def test_baseline_cmax_is_offline_unless_live(tmp_path):
    from spikegyro.events.core import Recording
    from spikegyro.events.io import write_recording
    from spikegyro.stream.writer import read_predictions

    path = tmp_path / "pan.h5"
    omega = np.radians([0.0, 60.0, 0.0])
    events = point_track_events(omega, seed=4, duration_s=0.1, points=3000)
    write_recording(path, Recording(events, None, {"fx": F, "fy": F, "cx": 120.0, "cy": 90.0}))
    for engine in ([], ["--live"]):
        out = tmp_path / f"b{len(engine)}.csv"
        done = CliRunner().invoke(app, ["baseline", "cmax", str(path), *engine, "-o", str(out)])
        assert done.exit_code == 0, done.output
        assert ("causal windows" in done.output) == bool(engine), done.output
        pred = read_predictions(out)
        for w in pred["omega"][pred["t_us"] > events.t[0] + 50_000]:
            assert_close_omega(w, omega)
    bad = CliRunner().invoke(
        app, ["baseline", "cmax", str(path), "--window-ms", "20", "-o", "x.csv"]
    )
    assert bad.exit_code != 0 and "--live" in str(bad.exception)


def test_offline_series_per_window_for_evaluation():
    from types import SimpleNamespace

    omega = np.radians([30.0, 0.0, -90.0])
    events = point_track_events(omega, seed=6, duration_s=0.1, points=3000).shift_time(500_000)
    window = SimpleNamespace(events=events, omega=np.tile(omega, (100, 1)), t_start_us=500_000)
    pred = predict_windows_offline([window], first_step=50)
    assert pred.shape == (1, 100, 3) and not pred[0, :50].any()
    for w in pred[0, 50:]:
        assert_close_omega(w, omega)


@pytest.fixture(scope="module", params=[150.0, 3000.0], ids=["steady", "changing"])
def short_recording(request):
    """100 ms of a simulated DAVIS240C (noise, hot pixels, lens) under a rotation whose
    acceleration has a standard deviation of 150 (nearly steady) or 3,000 deg/s² per axis."""
    from spikegyro.sim.dataset import SimConfig, simulate_sequence
    from spikegyro.sim.trajectory import TrajectoryConfig

    motion = TrajectoryConfig(accel_std_deg=request.param)
    sim = SimConfig(duration_ms=100, sensor="davis240c", trajectory=motion)
    return simulate_sequence(sim, 0, 1, split="test")


@pytest.mark.parametrize("span_ms", [10, 30, 100])
def test_offline_is_no_worse_than_one_estimate_over_a_short_recording(short_recording, span_ms):
    from spikegyro.cmax.problem import camera_from_attrs
    from spikegyro.cmax.search import estimate_whole

    rec = short_recording.slice_time(0, span_ms * 1000)
    camera = camera_from_attrs(rec.attrs, *rec.events.sensor_size)
    est = estimate_offline(rec.events, camera)
    truth = np.column_stack([np.interp(est.t_us, rec.gyro.t, w) for w in rec.gyro.omega.T])
    offline = np.linalg.norm(est.omega - truth, axis=1).mean()
    whole = np.linalg.norm(estimate_whole(rec.events, camera) - truth, axis=1).mean()
    assert offline <= whole + 1e-9
    # Where the rate changes by hundreds of deg/s over the span, each estimate follows it.
    if span_ms == 100 and np.ptp(np.degrees(truth), axis=0).max() > 100:
        assert offline < 0.5 * whole
