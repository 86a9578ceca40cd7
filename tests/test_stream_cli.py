"""``spikegyro predict`` end to end: Event Camera Dataset folder, calibration, gyro, errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from stream_helpers import random_events

from spikegyro.events.core import GyroTrace, Recording
from spikegyro.events.io import write_gyro_txt, write_recording
from spikegyro.models.registry import save_checkpoint
from spikegyro.models.snn6 import SNN6
from spikegyro.stream.writer import read_predictions


@pytest.fixture(autouse=True)
def _spec_cache(tmp_path, monkeypatch):
    # predict caches the network's spec; keep it out of the user's home
    monkeypatch.setenv("SPIKEGYRO_CACHE", str(tmp_path / "spec-cache"))


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "spikegyro", "predict", *map(str, args)],
        capture_output=True,
        text=True,
    )


def test_predict_ecd_folder_with_calibration_and_gyro(tmp_path):
    torch.manual_seed(0)
    spec = {"representation": "spikes", "sensor": [80, 64], "scale": 1.0, "output": "per_step"}
    ckpt = save_checkpoint(tmp_path / "snn6.pt", SNN6(), name="snn6", model_kwargs={},
                           input_spec=spec)  # fmt: skip
    # a 96x72 sensor with its own (distorted) optics, recorded like the Event Camera Dataset
    events = random_events(96, 72, 120, rate=0.01, seed=3, t0_us=2_000_000)
    t = np.arange(1_990_000, 2_130_000, 1000)
    gyro = GyroTrace.from_arrays(t, np.column_stack([0 * t + 0.1, 0 * t - 0.2, 0 * t + 0.3]))
    folder = write_recording(tmp_path / "ecd", Recording(events=events))
    write_gyro_txt(tmp_path / "gyro.txt", gyro)
    (folder / "calib.txt").write_text("210 209 47.5 35.5 -0.3 0.1 0.0002 -0.0005 0.0\n")
    out = tmp_path / "pred.csv"
    # the folder's calib.txt is picked up without --calib
    # the gyro is mounted with its x and y axes reversed: --imu-to-camera undoes that
    proc = _run(folder, "--checkpoint", ckpt, "--width", 96, "--height", 72, "--gyro",
                tmp_path / "gyro.txt", "--imu-to-camera=-x,-y,z", "--out", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    pred = read_predictions(out)
    assert len(pred["t_us"]) == 120
    assert pred["t_us"][0] == 2_001_000 and np.all(np.diff(pred["t_us"]) == 1000)
    np.testing.assert_allclose(pred["gyro_omega"], np.tile([-0.1, 0.2, 0.3], (120, 1)), atol=1e-6)
    assert "real time" in proc.stderr and "RMSE" in proc.stderr
    assert "using the calibration" in proc.stderr
    assert out.with_suffix(".png").stat().st_size > 0
    # A real recording (not from the simulator): one line points to contrast maximization.
    assert "--method cmax" in proc.stderr and "not yet accurate" in proc.stderr


def test_predict_user_errors_are_one_line(tmp_path, monkeypatch, capsys):
    from spikegyro import cli

    events = write_recording(
        tmp_path / "rec.h5", Recording(events=random_events(240, 180, 5, 0.001))
    )
    monkeypatch.setattr(sys, "argv", ["spikegyro", "predict", str(events), "--checkpoint",
                                      str(tmp_path / "missing.pt")])  # fmt: skip
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "missing.pt" in err


def test_predict_on_the_event_clock_writes_step_columns_and_sensor_pixels(tmp_path):
    """`--clock events:N` rows every ms hold the latest step (its events, length and age);
    `--pixels sensor` reads the sensor's own pixels around the principal point."""
    torch.manual_seed(0)
    spec = {"representation": "spikes", "sensor": [80, 64], "scale": 1.0, "output": "per_step"}
    ckpt = save_checkpoint(tmp_path / "snn6.pt", SNN6(), name="snn6", model_kwargs={},
                           input_spec=spec)  # fmt: skip
    events = random_events(96, 72, 150, rate=0.01, seed=4)
    rec = write_recording(tmp_path / "rec.h5", Recording(events=events))
    out = tmp_path / "pred.csv"
    proc = _run(rec, "--checkpoint", ckpt, "--intrinsics", 100, 100, 48, 36, "--clock",
                "events:300:2-10", "--pixels", "sensor", "--out", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    pred = read_predictions(out)
    assert np.all(np.diff(pred["t_us"]) == 1000) and len(pred["t_us"]) > 100
    assert {"events", "step_ms", "age_ms"} <= set(pred)
    assert np.all((pred["step_ms"] >= 2) & (pred["step_ms"] <= 10))
    assert np.all(pred["age_ms"] >= 0) and np.all(pred["age_ms"] < 11)
    # a window of 80x64 of 96x72 pixels: about 74 % of the events, 300 per full step
    full = pred["events"][pred["step_ms"] < 10]
    assert full.size and np.all(full >= 300)
    for bad in (("--clock", "events:-3"), ("--pixels", "both")):
        proc = _run(rec, "--checkpoint", ckpt, "--intrinsics", 100, 100, 48, 36, *bad,
                    "--out", tmp_path / "bad.csv")  # fmt: skip
        assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0, proc.stderr
        assert bad[0] in proc.stderr and not (tmp_path / "bad.csv").exists()
