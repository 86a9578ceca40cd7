"""``spikegyro evaluate-real``: SNN-6, contrast maximization and the mean predictor against a gyro
on a real recording, with the same metrics, bins and figures as ``spikegyro evaluate``.

Time axis. The span runs from ``--start`` to ``--end`` (seconds after the first event, whose time
is rounded down to a whole millisecond: ``t0``), cut into 1 ms steps ``[t0 + k ms, t0 + (k+1) ms)``.
Each model gives one omega per step (rad/s, camera frame):

- SNN-6 streams over the whole span with its state carried (as ``spikegyro predict``), the output
  of step k stamped at its end;
- CMax (:func:`spikegyro.baselines.cmax.predict_stream`, default settings, as
  ``spikegyro baseline cmax``) estimates every few ms from the events before it, each estimate
  held until the next;
- the mean predictor answers a constant: zero, or the training mean of ``--mean-data DIR``.

The gyro (its own rate, rotated into the camera frame with ``--imu-to-camera`` and shifted by
the clock offset) is interpolated linearly to each step's end. Steps from ``--warmup-ms`` on
(default 50 ms, the SNN's settling time, as in simulation) count in the **per-ms metrics**.

Windows. From the end of the warm-up the span is tiled by the user's windows, by time
(``--windows-ms``) or by event count (``--windows-events``); a partial window at the end is left
out. The **per-window metrics** compare each model's mean over a window with the gyro's exact
mean over it (of the piecewise-linear interpolant); besides, CMax makes one estimate from all
the events of each window ("CMax (window)"), the usual use in the CMax literature.

Clock offset. CMax over short windows (``OffsetConfig``) is cross-correlated with the gyro over a
range of offsets (:func:`spikegyro.evaluate.offset.fit_time_offset`). The best offset is always
reported; it is applied only with ``--gyro-offset auto`` (a number applies that offset in ms).

Outputs in ``OUT``: ``metrics.json``, ``predictions.csv`` (per ms), ``windows.csv``,
``traces.png``, ``offset.png``, ``bins.png``, ``axes_<model>.png``, ``report.html``,
``report.md`` (written by :mod:`spikegyro.evaluate.real_report`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import Progress

from spikegyro.baselines import cmax
from spikegyro.baselines.mean import training_mean_omega
from spikegyro.checks import check_input, check_output_dir, sensor_option
from spikegyro.errors import InputError
from spikegyro.evaluate import metrics
from spikegyro.evaluate.bins import SPEED_BIN_EDGES_DEG_S, bin_labels, empty_bins, per_bin_metrics
from spikegyro.evaluate.console import print_summary, write_json
from spikegyro.evaluate.offset import event_sample_times, fit_time_offset
from spikegyro.evaluate.real_report import write_figures, write_real_report, write_tables
from spikegyro.evaluate.report import (
    display_name,
)
from spikegyro.events.calib import Calibration, resolve_calibration
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.events.imu import (
    IMU_TO_CAMERA_HELP,
    covers,
    imu_rotation,
    rotate_gyro,
    sampling_interval_us,
    shift_gyro,
    window_means,
)
from spikegyro.events.io import atomic_dir, read_gyro, read_recording
from spikegyro.stream.model import DEFAULT_CHECKPOINT, load_streaming_model
from spikegyro.stream.predict import WARMUP_STEPS, StreamPredictor, event_mapper, model_camera

REAL_METRICS_FORMAT = "spikegyro-real-metrics/1"
BIN_US = 1000
DEFAULT_WINDOW_MS = 20.0
SNN_CHUNK_MS = 20
MIN_OFFSET_CORRELATION = 0.5
"""A best fit correlating less than this is reported as undetermined."""


@dataclass(frozen=True)
class OffsetConfig:
    """How the clock offset is fitted.

    Attributes:
        max_offset_ms: candidate offsets span ``[-max, +max]`` ms.
        step_ms: grid step of the candidates, ms (a parabola refines below it).
        window_ms: CMax estimates over windows this long, ms (short: the gyro's changes show),
            each from its own events alone (no warm start, which would lag).
        stride_ms: one estimate every this many ms.
    """

    max_offset_ms: float = 30.0
    step_ms: float = 0.25
    window_ms: float = 10.0
    stride_ms: int = 5


@dataclass(frozen=True)
class RealEvalConfig:
    """What ``evaluate-real`` scores (see the module docstring)."""

    windows_ms: float | None = DEFAULT_WINDOW_MS
    windows_events: int | None = None
    start_s: float = 0.0
    end_s: float | None = None
    warmup_ms: int = WARMUP_STEPS
    gyro_offset: str = "0"
    offset: OffsetConfig = OffsetConfig()


def parse_gyro_offset(text: str) -> float | None:
    """``--gyro-offset``: milliseconds added to the gyro's timestamps, or None for ``auto``."""
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"--gyro-offset '{text}': give milliseconds (e.g. -2.5) or 'auto'."
        ) from None
    if not math.isfinite(value):
        raise InputError(f"--gyro-offset '{text}': must be a finite number of milliseconds.")
    return value


def time_windows(begin_us: int, end_us: int, length_us: float) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive whole windows ``[a, a + length)`` from ``begin_us`` up to ``end_us`` (µs)."""
    count = int((end_us - begin_us) // length_us) if end_us > begin_us else 0
    starts = begin_us + np.round(np.arange(count) * length_us).astype(np.int64)
    ends = begin_us + np.round(np.arange(1, count + 1) * length_us).astype(np.int64)
    return starts, ends


def event_windows(
    t_us: np.ndarray, begin_us: int, end_us: int, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive windows of exactly ``count`` events among those in ``[begin_us, end_us)``;
    each spans from its first event's time to just after its last (µs)."""
    i0, i1 = np.searchsorted(t_us, [begin_us, end_us], side="left")
    firsts = np.arange(int(i0), int(i1) - count + 1, count, dtype=np.int64)
    return t_us[firsts], t_us[firsts + count - 1] + 1


def bin_means(
    values: np.ndarray, t0_us: int, starts_us: np.ndarray, ends_us: np.ndarray
) -> np.ndarray:
    """Mean of a per-ms series over each ``[start, end)`` µs, each step k taken as constant over
    ``[t0 + k ms, t0 + (k+1) ms)`` (overlap-weighted); (n, 3), the units of ``values``."""
    cumulative = np.concatenate([np.zeros((1, 3)), np.cumsum(values, axis=0)])

    def integral(t_us: np.ndarray) -> np.ndarray:
        x = np.clip((np.asarray(t_us, dtype=np.float64) - t0_us) / BIN_US, 0, len(values))
        k = np.minimum(np.floor(x).astype(np.int64), len(values) - 1)
        return cumulative[k] + (x - k)[:, None] * values[k]

    span = (np.asarray(ends_us, dtype=np.float64) - starts_us)[:, None] / BIN_US
    return (integral(ends_us) - integral(starts_us)) / np.maximum(span, 1e-12)


def _snn_per_ms(
    events: EventArray,
    checkpoint: Path,
    calibration: Calibration | None,
    t0: int,
    steps: int,
    source: str,
    progress: Any,
) -> tuple[np.ndarray, dict[str, Any]]:
    engine, payload = load_streaming_model(checkpoint)
    spec = payload.get("input", {})
    mapper = event_mapper(events.sensor_size, spec, calibration, source)
    predictor = StreamPredictor(engine, model_camera(spec).width, t0)
    engine.reset()
    outputs = []
    for k in range(0, steps, SNN_CHUNK_MS):
        chunk = events.slice_time(t0 + k * BIN_US, t0 + (k + SNN_CHUNK_MS) * BIN_US)
        outputs.append(predictor.push(mapper(chunk))[1])
        progress(min(k + SNN_CHUNK_MS, steps), steps)
    outputs.append(predictor.finish(t0 + steps * BIN_US)[1])
    omega = np.concatenate(outputs)
    if omega.shape[0] != steps:
        raise RuntimeError(f"SNN gave {omega.shape[0]} steps, expected {steps}")
    return omega, payload


def _cmax_windows(
    events: EventArray,
    camera: Any,
    config: cmax.CMaxConfig,
    starts: np.ndarray,
    ends: np.ndarray,
    progress: Any,
) -> np.ndarray:
    """One CMax estimate from all the events of each window, for its middle (rad/s, (n, 3))."""
    out = np.zeros((len(starts), 3))
    for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        out[i] = cmax.estimate_window(events.slice_time(a, b), camera, config, t_ref_us=(a + b) / 2)
        progress(i + 1, len(starts))
    return out


def _load_gyro(
    recording_gyro: GyroTrace | None, gyro_path: Path | None, rotation: np.ndarray | None
) -> tuple[GyroTrace, str]:
    if gyro_path is not None:
        trace, source = read_gyro(gyro_path), str(gyro_path)
    elif recording_gyro is not None:
        trace, source = recording_gyro, "the recording's own gyro"
    else:
        raise InputError(
            "no gyro: pass --gyro FILE (ECD imu.txt 't ax ay az gx gy gz' or 't wx wy wz')."
        )
    sampling_interval_us(trace)  # at least two samples
    return (trace if rotation is None else rotate_gyro(trace, rotation)), source


def _check_overlap(
    gyro: GyroTrace,
    offset_ms: float | None,
    config: RealEvalConfig,
    begin_us: int,
    end_us: int,
    source: str,
) -> None:
    """Fail before any model runs when the gyro, at any offset that may be applied, cannot
    overlap the scored span ``[begin_us, end_us]`` (events' clock)."""
    if offset_ms is None:
        slack = config.offset.max_offset_ms * 1000
        lo, hi = gyro.t[0] - slack, gyro.t[-1] + slack
    else:
        lo, hi = gyro.t[0] + offset_ms * 1000, gyro.t[-1] + offset_ms * 1000
    if hi < begin_us or lo > end_us:
        raise InputError(
            f"{source}: the gyro ({gyro.t[0] / 1e6:.6f} to {gyro.t[-1] / 1e6:.6f} s) does not "
            f"cover the scored span ({begin_us / 1e6:.6f} to {end_us / 1e6:.6f} s on the events' "
            "clock); check the file's clock or pass --gyro-offset."
        )


def _method_results(
    name: str, method: str, pred: np.ndarray, gt: np.ndarray, scored: np.ndarray
) -> dict[str, Any]:
    """Per-ms metrics over the scored steps (one pseudo-window, every step evaluated)."""
    p, g = pred[scored][None], gt[scored][None]
    return {
        "name": name,
        "method": method,
        "metrics": metrics.summary(p, g, start=0),
        "per_bin": per_bin_metrics(p, g, start=0),
    }


def _window_results(window_pred: np.ndarray, window_gt: np.ndarray) -> dict[str, Any] | None:
    if not len(window_gt):
        return None
    m = metrics.summary(window_pred[None], window_gt[None], start=0)
    return {**m, "n_windows": m["n_pairs"]}


def run_real_evaluation(
    recording: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    gyro: str | os.PathLike | None = None,
    calib: str | os.PathLike | None = None,
    intrinsics: tuple[float, float, float, float] | None = None,
    checkpoint: str | os.PathLike | None = None,
    imu_to_camera: str | None = None,
    mean_data: str | os.PathLike | None = None,
    config: RealEvalConfig | None = None,
    sensor: tuple[int, int] | None = None,
    console: Console | None = None,
) -> dict[str, Any]:
    """Score SNN-6, CMax and the mean predictor against a gyro on a real recording.

    Args:
        recording: an event file or Event Camera Dataset folder (``spikegyro.events.io``).
        out_dir: output folder (see the module docstring).
        gyro: gyro/IMU text file; default the recording's own (``imu.txt``/``gyro.txt`` of an
            ECD folder, ``ang_*`` of an HDF5 file).
        calib, intrinsics: the sensor's calibration (``--calib``/``--intrinsics`` of
            ``predict``); an ECD folder's ``calib.txt`` by default.
        checkpoint: the SNN; default the shipped pretrained SNN-6.
        imu_to_camera: ``--imu-to-camera`` text (:func:`spikegyro.events.imu.imu_rotation`).
        mean_data: dataset folder whose training mean the mean predictor answers (default 0).
        config: windows, span, warm-up and clock offset.
        sensor: (width, height) for text files that do not say (default 240x180).

    Returns:
        The dict written to ``metrics.json``.
    """
    config = config or RealEvalConfig()
    console = console or Console(stderr=True)
    recording, out_dir = Path(recording), check_output_dir(out_dir)
    checkpoint = Path(checkpoint) if checkpoint is not None else DEFAULT_CHECKPOINT
    check_input(checkpoint, "--checkpoint")
    if (config.windows_ms is None) == (config.windows_events is None):
        raise InputError("give one of --windows-ms MS and --windows-events N.")
    if config.end_s is not None and config.end_s <= config.start_s:
        raise InputError(f"--end {config.end_s} s must be after --start {config.start_s} s.")
    if config.start_s < 0 or config.warmup_ms < 0:
        raise InputError("--start and --warmup-ms must not be negative.")
    offset_ms = parse_gyro_offset(config.gyro_offset)
    rotation = None if imu_to_camera is None else imu_rotation(imu_to_camera)
    calibration, calib_file = resolve_calibration(recording, calib, intrinsics)
    rec = read_recording(recording, sensor=sensor)
    if not len(rec.events):
        raise InputError(f"{recording}: the file holds no events.")
    raw_gyro, gyro_source = _load_gyro(rec.gyro, Path(gyro) if gyro else None, rotation)
    warnings: list[str] = []

    t_first = int(rec.events.t[0]) // BIN_US * BIN_US
    t0 = t_first + round(config.start_s * 1e6)
    t_end = (
        int(rec.events.t[-1]) + 1 if config.end_s is None else t_first + round(config.end_s * 1e6)
    )
    steps = -(-(t_end - t0) // BIN_US)
    events = rec.events.slice_time(t0, t0 + steps * BIN_US)
    if not len(events) or steps <= config.warmup_ms:
        raise InputError(
            f"{recording}: {len(events):,} events in {steps} ms between --start and --end; the "
            f"span must be longer than the {config.warmup_ms} ms warm-up."
        )
    ends = t0 + BIN_US * np.arange(1, steps + 1, dtype=np.int64)
    _check_overlap(
        raw_gyro, offset_ms, config, t0 + config.warmup_ms * BIN_US, ends[-1], gyro_source
    )
    width, height = events.sensor_size
    # CMax undistorts each event to its ray itself: it takes the raw events and the calibration.
    camera = calibration or cmax.camera_from_attrs(rec.attrs, width, height)
    cmax_config = cmax.CMaxConfig()

    # The user's windows, tiled from the end of the warm-up.
    begin = t0 + config.warmup_ms * BIN_US
    if config.windows_events is not None:
        w_starts, w_ends = event_windows(
            events.t, begin, t0 + steps * BIN_US, config.windows_events
        )
    else:
        w_starts, w_ends = time_windows(begin, t0 + steps * BIN_US, config.windows_ms * 1000)
    if not len(w_starts):
        size = (
            f"{config.windows_events:,} events"
            if config.windows_events is not None
            else f"{config.windows_ms:g} ms"
        )
        raise InputError(
            f"{recording}: no whole window of {size} after the {config.warmup_ms} ms warm-up; "
            "choose smaller windows, a shorter --warmup-ms or a longer span."
        )

    offset_cfg = config.offset
    with Progress(console=console, transient=True) as bar:

        def tracker(label: str) -> Any:
            task = bar.add_task(label, total=None)
            return lambda done, total: bar.update(task, completed=done, total=total)

        snn, payload = _snn_per_ms(
            events, checkpoint, calibration, t0, steps, str(recording), tracker("SNN-6")
        )
        t_cmax, w_cmax = cmax.predict_stream(events, camera, cmax_config, progress=tracker("CMax"))
        cmax_ms = cmax.per_ms(t_cmax, w_cmax, ends)  # as `spikegyro baseline cmax` writes it
        cmax_win = _cmax_windows(
            events, camera, cmax_config, w_starts, w_ends, tracker("CMax per window")
        )
        # Independent windows: a warm-started stream lags fast changes (by ~2 ms at a 5 ms
        # stride on simulated data), which would bias the offset.
        window_us = round(offset_cfg.window_ms * 1000)
        off_ends = np.arange(t0 + window_us, t0 + steps * BIN_US + 1, offset_cfg.stride_ms * BIN_US)
        w_off = _cmax_windows(
            events,
            camera,
            cmax_config,
            off_ends - window_us,
            off_ends,
            tracker("CMax for the clock offset"),
        )
    fit = fit_time_offset(
        event_sample_times(events.t, off_ends - window_us, off_ends),
        w_off,
        raw_gyro,
        max_offset_us=offset_cfg.max_offset_ms * 1000,
        step_us=offset_cfg.step_ms * 1000,
    )
    if fit["offset_us"] is None:
        warnings.append(f"no clock offset could be fitted: {fit['reason']}")
    elif fit["correlation"] < MIN_OFFSET_CORRELATION:
        warnings.append(
            f"the estimates and the gyro hardly correlate at any offset (at best "
            f"{fit['correlation']:.2f}): the motion does not vary enough for CMax over "
            f"{offset_cfg.window_ms:g} ms to pin the clock offset down; do not apply it."
        )
    elif fit.get("at_edge"):
        warnings.append(
            f"the best clock offset lies at the edge of ±{offset_cfg.max_offset_ms:g} ms; the "
            "true one may lie outside."
        )
    if offset_ms is None:
        applied_us = fit["offset_us"] if fit["offset_us"] is not None else 0.0
        if fit["offset_us"] is None:
            warnings.append("--gyro-offset auto: no fit, so no offset is applied.")
    else:
        applied_us = offset_ms * 1000
    trace = shift_gyro(raw_gyro, applied_us)

    gt = trace.interpolate(ends)
    step_index = np.arange(steps)
    scored = (step_index >= config.warmup_ms) & covers(trace, ends)
    if not scored.any():
        raise InputError(
            f"{gyro_source}: the gyro ({trace.t[0] / 1e6:.6f} to {trace.t[-1] / 1e6:.6f} s) does "
            f"not cover the scored span ({(t0 + config.warmup_ms * BIN_US) / 1e6:.6f} to "
            f"{ends[-1] / 1e6:.6f} s on the events' clock)."
        )
    if (~scored[config.warmup_ms :]).any():
        warnings.append(
            f"{int((~scored[config.warmup_ms :]).sum())} steps after the warm-up lie outside the "
            "gyro's span and are not scored."
        )
    win_ok = covers(trace, w_starts) & covers(trace, w_ends)
    if not win_ok.all():
        warnings.append(f"{int((~win_ok).sum())} windows lie outside the gyro's span; left out.")
    w_gt = window_means(trace, w_starts, w_ends)

    if mean_data is not None:
        mean_omega, mean_source = training_mean_omega(mean_data, "train"), f"{mean_data}/train"
    else:
        mean_omega, mean_source = np.zeros(3), "zero"
    mean_ms = np.broadcast_to(mean_omega, (steps, 3)).copy()

    snn_name = display_name(payload)
    per_ms = {snn_name: ("snn", snn), "CMax": ("cmax", cmax_ms), "Mean": ("mean", mean_ms)}
    models: dict[str, dict[str, Any]] = {}
    window_pred: dict[str, np.ndarray] = {}
    for name, (method, series) in per_ms.items():
        models[name] = _method_results(name, method, series, gt, scored)
        window_pred[name] = bin_means(series, t0, w_starts, w_ends)
    window_pred["CMax (window)"] = cmax_win
    models["CMax (window)"] = {"name": "CMax (window)", "method": "cmax_window", "metrics": None}
    for name, pred in window_pred.items():
        models[name]["window_metrics"] = _window_results(pred[win_ok], w_gt[win_ok])
    models[snn_name]["source"] = str(checkpoint)
    models["Mean"]["omega_rad_s"] = mean_omega.tolist()
    models["Mean"]["source"] = mean_source
    empty = empty_bins(models[snn_name]["per_bin"])
    if empty:
        warnings.append(f"no scored step in speed bin(s) {', '.join(empty)} deg/s; left empty.")

    num_events = np.searchsorted(events.t, w_ends) - np.searchsorted(events.t, w_starts)
    result = {
        "format": REAL_METRICS_FORMAT,
        "data": {
            "recording": str(recording),
            "calibration": str(calib_file)
            if calib_file
            else ("--intrinsics" if intrinsics else None),
            "sensor": [width, height],
            "t0_s": t0 / 1e6,
            "steps_ms": steps,
            "events": len(events),
            "event_rate_per_s": len(events) / (steps / 1000),
            "warmup_ms": config.warmup_ms,
            "scored_steps": int(scored.sum()),
            "windows": {
                "by": "events" if config.windows_events is not None else "time",
                "size": config.windows_events
                if config.windows_events is not None
                else config.windows_ms,
                "count": len(w_starts),
                "scored": int(win_ok.sum()),
                "start_s": (w_starts / 1e6).tolist(),
                "end_s": (w_ends / 1e6).tolist(),
                "events": num_events.tolist(),
            },
        },
        "gyro": {
            "source": gyro_source,
            "samples": len(raw_gyro),
            "span_s": [raw_gyro.t[0] / 1e6, raw_gyro.t[-1] / 1e6],
            "sampling_interval": sampling_interval_us(raw_gyro),
            "imu_to_camera": None if rotation is None else rotation.tolist(),
            "offset_fit": fit,
            "offset_applied_us": float(applied_us),
            "offset_convention": "added to the gyro's timestamps: gyro(t - offset) is the "
            "reference at event time t",
        },
        "bins": {
            "edges_deg_s": [None if math.isinf(e) else e for e in SPEED_BIN_EDGES_DEG_S],
            "labels": bin_labels(),
        },
        "models": models,
        "windows_omega_rad_s": {
            "gyro": w_gt.tolist(),
            **{name: pred.tolist() for name, pred in window_pred.items()},
        },
        "warnings": warnings,
    }
    with atomic_dir(out_dir) as staging:
        write_tables(staging, ends, scored, gt, per_ms, w_starts, w_ends, num_events, win_ok,
                     w_gt, window_pred)  # fmt: skip
        write_json(staging / "metrics.json", result)
        write_figures(staging, result, t0, ends, per_ms, trace, w_starts, w_ends, cmax_win)
        write_real_report(staging, result)
    print_summary(
        console,
        f"{recording}: {int(scored.sum())} steps, {int(win_ok.sum())} windows",
        [m for m in models.values() if m["metrics"] is not None]
        + [models["CMax (window)"] | {"metrics": {}}],
        warnings,
        window_label="per window",
        start_ms=config.warmup_ms,
    )
    if fit["offset_us"] is not None:
        console.print(
            f"gyro sampled every {result['gyro']['sampling_interval']['median_us'] / 1000:.3f} "
            f"ms; best clock offset {fit['offset_us'] / 1000:+.2f} ms (correlation "
            f"{fit['correlation']:.3f}), applied {applied_us / 1000:+.2f} ms"
        )
    console.print(f"wrote {out_dir}/metrics.json, predictions.csv, windows.csv, report.html")
    return result


def evaluate_real(
    recording: Path = typer.Argument(
        ..., help="Event file: .h5/.hdf5, .npz, events.txt (t x y p) or an ECD folder."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    gyro: Path = typer.Option(
        None,
        "--gyro",
        help="Gyro file: ECD imu.txt 't ax ay az gx gy gz' or 't wx wy wz' (rad/s, seconds); "
        "default the recording's own.",
    ),
    calib: Path = typer.Option(
        None,
        "--calib",
        help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt; taken from an ECD "
        "folder by default).",
    ),
    intrinsics: tuple[float, float, float, float] = typer.Option(
        None, "--intrinsics", help="Sensor pinhole intrinsics fx fy cx cy (pixels), no distortion."
    ),
    checkpoint: Path = typer.Option(
        None, "--checkpoint", help="SNN checkpoint (default: the shipped pretrained SNN-6)."
    ),
    windows_ms: float = typer.Option(
        None,
        "--windows-ms",
        min=0.001,
        help=f"Windows by time, ms (default {DEFAULT_WINDOW_MS:g}).",
    ),
    windows_events: int = typer.Option(
        None, "--windows-events", min=1, help="Windows by event count instead of by time."
    ),
    start: float = typer.Option(0.0, "--start", help="Start, seconds after the first event."),
    end: float = typer.Option(None, "--end", help="End, seconds after the first event."),
    warmup_ms: int = typer.Option(
        WARMUP_STEPS, "--warmup-ms", min=0, help="Steps (ms) after --start that are not scored."
    ),
    imu_to_camera: str = typer.Option(None, "--imu-to-camera", help=IMU_TO_CAMERA_HELP),
    gyro_offset: str = typer.Option(
        "0",
        "--gyro-offset",
        help="Milliseconds added to the gyro's timestamps, or 'auto' for the best fit "
        "(always reported).",
    ),
    max_offset_ms: float = typer.Option(
        OffsetConfig.max_offset_ms, "--max-offset-ms", min=0.5, help="Clock offsets searched, ±ms."
    ),
    mean_data: Path = typer.Option(
        None, "--mean-data", help="Dataset whose training mean the mean predictor answers (else 0)."
    ),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
) -> None:
    """Score SNN-6, CMax and the mean predictor against a gyro on a real recording."""
    config = RealEvalConfig(
        windows_ms=DEFAULT_WINDOW_MS
        if windows_ms is None and windows_events is None
        else windows_ms,
        windows_events=windows_events,
        start_s=start,
        end_s=end,
        warmup_ms=warmup_ms,
        gyro_offset=gyro_offset,
        offset=replace(OffsetConfig(), max_offset_ms=max_offset_ms),
    )
    run_real_evaluation(
        recording,
        out,
        gyro=gyro,
        calib=calib,
        intrinsics=intrinsics,
        checkpoint=checkpoint,
        imu_to_camera=imu_to_camera,
        mean_data=mean_data,
        config=config,
        sensor=sensor_option(width, height),
    )
