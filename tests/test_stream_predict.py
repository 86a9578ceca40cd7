"""Streaming prediction from files: every input format, geometry mapping, gyro metrics, memory."""

from __future__ import annotations

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
import torch
from stream_helpers import TinySNN, random_events

from spikegyro import metrics
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration
from spikegyro.events.core import GyroTrace, Recording
from spikegyro.events.io import write_gyro_txt, write_recording
from spikegyro.events.representations import spike_tensor
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.predict import WARMUP_STEPS, ErrorStats, predict_stream
from spikegyro.stream.stateful import StreamingSNN
from spikegyro.stream.writer import read_predictions

H, W = 24, 32
SPEC = {"representation": "spikes", "sensor": [W, H], "scale": 1.0, "output": "per_step"}
T0_US = 1_500_000  # files need not start at 0


@pytest.fixture(scope="module")
def model():
    return TinySNN()


@pytest.fixture(scope="module")
def engine(model):
    return StreamingSNN(spec_from_model(model, (2, H, W)))


@pytest.fixture(scope="module")
def recording():
    events = random_events(W, H, 150, rate=0.01, seed=7, t0_us=T0_US)
    t = np.arange(T0_US - 5000, T0_US + 160_000, 1000)
    omega = np.column_stack([np.sin(t / 3e4), np.cos(t / 5e4), 0.5 + 0 * t])
    return Recording(events=events, gyro=GyroTrace.from_arrays(t, omega))


def _batch(model, events, t0_us, steps):
    x = spike_tensor(events.x, events.y, events.t, events.p, height=H, width=W,
                     t_start_us=t0_us, num_bins=steps)  # fmt: skip
    with torch.no_grad():
        return model.forward_with_spikes(torch.from_numpy(x)[None])[0][0].T.numpy()


@pytest.mark.parametrize("name", ["rec.h5", "rec.npz", "events.txt", "ecd_folder"])
def test_every_format_end_to_end(tmp_path, model, engine, recording, name):
    path = write_recording(tmp_path / name, recording)
    out = tmp_path / "pred.csv"
    result = predict_stream(path, engine, SPEC, out, sensor=(W, H), chunk_events=500)
    ev = recording.events
    steps = (int(ev.t[-1]) - T0_US) // 1000 + 1
    pred = read_predictions(out)
    assert result.steps == steps == len(pred["t_us"])
    # prediction k is stamped at the end of bin k
    np.testing.assert_array_equal(pred["t_us"], T0_US + 1000 * np.arange(1, steps + 1))
    expected = _batch(model, ev, T0_US, steps)
    assert np.abs(expected).max() > 0
    np.testing.assert_allclose(pred["omega"], expected, atol=1e-4 * np.abs(expected).max())


def test_start_end_select_a_span(tmp_path, model, engine, recording):
    path = write_recording(tmp_path / "rec.h5", recording)
    out = tmp_path / "pred.h5"
    predict_stream(path, engine, SPEC, out, start_s=0.02, end_s=0.07)
    pred = read_predictions(out)
    t0 = T0_US + 20_000
    np.testing.assert_array_equal(pred["t_us"], t0 + 1000 * np.arange(1, 51))
    # the network starts from rest at --start and sees only events in [start, end)
    ev = recording.events.slice_time(t0, T0_US + 70_000)
    expected = _batch(model, ev, t0, 50)
    np.testing.assert_allclose(pred["omega"], expected, atol=1e-4 * np.abs(expected).max())


def test_gyro_columns_are_the_interpolated_reference(tmp_path, engine, recording):
    path = write_recording(tmp_path / "rec.h5", recording)
    gyro_path = tmp_path / "gyro.txt"
    write_gyro_txt(gyro_path, recording.gyro)
    out = tmp_path / "pred.csv"
    result = predict_stream(path, engine, SPEC, out, gyro_path=gyro_path)
    pred = read_predictions(out)
    t = pred["t_us"]
    truth = np.column_stack([np.sin(t / 3e4), np.cos(t / 5e4), 0.5 + 0 * t])
    np.testing.assert_allclose(pred["gyro_omega"], truth, atol=2e-6)  # linear interp of 1 kHz
    scored = t > T0_US + 50_000
    err = np.linalg.norm(pred["omega"][scored] - truth[scored], axis=1)
    assert result.stats["samples"] == scored.sum()
    assert result.stats["mean_error_deg_s"] == pytest.approx(np.degrees(err.mean()), rel=1e-4)
    assert result.plot is not None and result.plot.stat().st_size > 0


def test_stream_scores_are_the_evaluation_metrics(tmp_path, engine, recording):
    """The scores ``predict`` prints against a gyro are ``spikegyro.metrics`` on the
    rows it wrote (those after the warm-up, as one window scored from its first step)."""
    path = write_recording(tmp_path / "rec.h5", recording)
    gyro_path = tmp_path / "gyro.txt"
    write_gyro_txt(gyro_path, recording.gyro)
    out = tmp_path / "pred.h5"
    result = predict_stream(path, engine, SPEC, out, gyro_path=gyro_path, plot=False)
    pred = read_predictions(out)
    scored = pred["t_us"] > T0_US + WARMUP_STEPS * 1000
    s = metrics.summary(pred["omega"][None, scored], pred["gyro_omega"][None, scored], start=0)
    axes = {key: s["per_axis"][axis] for key, axis in zip("xyz", metrics.AXES, strict=True)}
    expected = {
        "mean_error_deg_s": s["mean_euclidean_error_deg_s"],
        "rmse_deg_s": s["rmse_deg_s"],
        **{f"rmse_{key}_deg_s": axis["rmse_deg_s"] for key, axis in axes.items()},
        **{f"mae_{key}_deg_s": axis["mean_abs_error_deg_s"] for key, axis in axes.items()},
    }
    got = dict(result.stats)
    assert got.pop("samples") == s["n_pairs"] == scored.sum()
    # the histogram's bins are 10^0.001 apart: its median is within 0.25 % of the exact one
    median = got.pop("median_relative_error")
    assert median == pytest.approx(s["median_relative_error"], rel=2.5e-3)
    assert got == pytest.approx(expected, rel=1e-5)  # the file holds float32


def test_error_stats_against_numpy():
    rng = np.random.default_rng(0)
    ref = rng.normal(size=(5000, 3))
    pred = ref + rng.normal(scale=0.3, size=(5000, 3))
    stats = ErrorStats()
    for i in range(0, 5000, 700):
        stats.add(pred[i : i + 700], ref[i : i + 700])
    s = stats.summary()
    err = np.linalg.norm(pred - ref, axis=1)
    rel = err / np.linalg.norm(ref, axis=1)
    assert s["rmse_deg_s"] == pytest.approx(np.degrees(np.sqrt((err**2).mean())), rel=1e-9)
    assert s["rmse_z_deg_s"] == pytest.approx(
        np.degrees(np.sqrt(((pred - ref)[:, 2] ** 2).mean())), rel=1e-9
    )
    assert s["median_relative_error"] == pytest.approx(np.median(rel), rel=3e-3)


def test_calibrated_sensor_is_reprojected(tmp_path, model, engine):
    # A 64x48 sensor with twice the focal length sees the model's 32x24 view in its centre.
    calib = Calibration(fx=2 * 200.0, fy=2 * 200.0, cx=31.5, cy=23.5)
    spec = {**SPEC, "intrinsics": [200.0, 200.0, 15.5, 11.5]}
    small = random_events(W, H, 60, rate=0.01, seed=9)
    # put each model pixel's event on one of the 2x2 sensor pixels whose ray rounds to it
    big = replace(small, x=(2 * small.x).astype(np.int16), y=(2 * small.y).astype(np.int16),
                  width=64, height=48)  # fmt: skip
    path = write_recording(tmp_path / "big.h5", Recording(events=big))
    out = tmp_path / "pred.csv"
    predict_stream(path, engine, spec, out, calibration=calib)
    t0 = int(small.t[0]) // 1000 * 1000
    expected = _batch(model, small, t0, len(read_predictions(out)["t_us"]))
    np.testing.assert_allclose(read_predictions(out)["omega"], expected, atol=1e-5)
    with pytest.raises(InputError, match="--calib"):
        predict_stream(path, engine, SPEC, tmp_path / "p2.csv")


def test_memory_stays_flat_for_long_files(tmp_path, engine):
    def peak_bytes(seconds: float) -> tuple[int, int]:
        events = random_events(W, H, int(seconds * 1000), rate=0.005, seed=11)
        path = write_recording(tmp_path / f"long_{seconds}.h5", Recording(events=events))
        tracemalloc.start()
        result = predict_stream(path, engine, SPEC, tmp_path / "p.h5", chunk_events=2_000)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak, result.steps

    peak_bytes(2.0)  # first call: one-off allocations (compiled-kernel loading, imports)
    short_peak, short_steps = peak_bytes(2.0)
    long_peak, long_steps = peak_bytes(16.0)
    assert long_steps >= 8 * short_steps - 8
    # 8x the events and steps, the same working set (chunks of 2k events)
    assert long_peak < 1.3 * short_peak, (short_peak, long_peak)


def test_a_span_without_events_is_an_input_error(tmp_path, engine, recording):
    path = write_recording(tmp_path / "rec.h5", recording)
    with pytest.raises(InputError, match="no events"):
        predict_stream(path, engine, SPEC, tmp_path / "p.csv", start_s=5.0)
    assert not (tmp_path / "p.csv").exists()
