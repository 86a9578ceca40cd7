"""``spikegyro evaluate-real``: SNN-6, contrast maximization and the mean predictor against a gyro
on a real recording, with the same metrics, bins and figures as ``spikegyro evaluate``.

Time axis. The span runs from ``--start`` to ``--end`` (seconds after the first event, whose time
is rounded down to a whole millisecond: ``t0``), cut into 1 ms steps ``[t0 + k ms, t0 + (k+1) ms)``.
Each model gives one omega per step (rad/s, camera frame):

- SNN-6 streams over the whole span with its state carried (as ``spikegyro predict``), the output
  of step k stamped at its end;
- CMax, offline (:func:`spikegyro.cmax.offline.estimate_offline`, as ``spikegyro baseline
  cmax``): an estimate every 10 ms from the events around it, interpolated to each step's end;
  beside it "CMax (live)" (:func:`spikegyro.cmax.series.predict_stream`, as ``spikegyro
  predict --method cmax``): each estimate from the events before it, interpolated likewise;
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import Progress

from spikegyro import metrics
from spikegyro.baselines.mean import training_mean_omega
from spikegyro.checks import check_output_dir
from spikegyro.cmax import series as cmax_series
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.offline import estimate_offline
from spikegyro.cmax.problem import camera_from_attrs
from spikegyro.cmax.search import estimate_window
from spikegyro.errors import InputError
from spikegyro.evaluate.bins import (
    SPEED_BIN_EDGES_DEG_S,
    bins_json,
    empty_bins,
    per_bin_metrics,
)
from spikegyro.evaluate.console import print_summary, write_json
from spikegyro.evaluate.offset import event_sample_times, fit_time_offset
from spikegyro.evaluate.real_report import write_figures, write_real_report, write_tables
from spikegyro.evaluate.report import display_name
from spikegyro.events.calib import Calibration, resolve_calibration
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.events.imu import (
    covers,
    imu_rotation,
    rotate_gyro,
    sampling_interval_us,
    shift_gyro,
    window_means,
)
from spikegyro.events.io import atomic_dir, read_gyro, read_recording
from spikegyro.events.windows import BIN_US, bin_means, event_windows, time_windows
from spikegyro.pretrained import resolve_checkpoint
from spikegyro.stream.clocked import hold_on_grid
from spikegyro.stream.engine import load_engine
from spikegyro.stream.model import DEFAULT_CHECKPOINT
from spikegyro.stream.predict import (
    WARMUP_STEPS,
    clocked_predictor,
    event_mapper,
    output_gain,
    spec_with,
)

REAL_METRICS_FORMAT = "spikegyro-real-metrics/1"
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
    speed_bins: tuple[float, ...] = SPEED_BIN_EDGES_DEG_S  # deg/s
    clock: str | None = None  # the SNN on this clock instead of its own (Clock.parse)
    pixels: str | None = None  # sensor or model pixels instead of the checkpoint's choice


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


def _snn_per_ms(
    events: EventArray,
    checkpoint: Path,
    calibration: Calibration | None,
    t0: int,
    steps: int,
    source: str,
    progress: Any,
    network: tuple[str | None, str | None] = (None, None),
) -> tuple[np.ndarray, dict[str, Any]]:
    # the exact stream; networks it cannot run (grid readout, log-polar input) go batched
    engine, payload = load_engine(checkpoint)
    spec = spec_with(payload.get("input", {}), *network)
    payload = {**payload, "input": spec}
    mapper = event_mapper(events.sensor_size, spec, calibration, source)
    predictor = clocked_predictor(engine, spec, t0)
    parts = []
    for k in range(0, steps, SNN_CHUNK_MS):
        chunk = events.slice_time(t0 + k * BIN_US, t0 + (k + SNN_CHUNK_MS) * BIN_US)
        parts.append(predictor.push(mapper(chunk)))
        progress(min(k + SNN_CHUNK_MS, steps), steps)
    parts.append(predictor.finish(t0 + steps * BIN_US))
    # 1 ms bins are stamped on the grid itself; event-clock steps are held until the next
    grid = t0 + BIN_US * np.arange(1, steps + 1)
    stamps, omega = (np.concatenate([p[i] for p in parts]) for i in (0, 1))
    omega = hold_on_grid(stamps, omega, grid)
    return omega * output_gain(spec, calibration), payload


def _cmax_windows(
    events: EventArray,
    camera: Any,
    config: CMaxConfig,
    starts: np.ndarray,
    ends: np.ndarray,
    progress: Any,
) -> np.ndarray:
    """One CMax estimate from all the events of each window, for its middle (rad/s, (n, 3))."""
    out = np.zeros((len(starts), 3))
    for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        out[i] = estimate_window(events.slice_time(a, b), camera, config, t_ref_us=(a + b) / 2)
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
    name: str,
    method: str,
    pred: np.ndarray,
    gt: np.ndarray,
    scored: np.ndarray,
    edges: tuple[float, ...],
) -> dict[str, Any]:
    """Per-ms metrics over the scored steps (one pseudo-window, every step evaluated)."""
    p, g = pred[scored][None], gt[scored][None]
    return {
        "name": name,
        "method": method,
        "metrics": metrics.summary(p, g, start=0),
        "per_bin": per_bin_metrics(p, g, edges, start=0),
    }


def _window_results(window_pred: np.ndarray, window_gt: np.ndarray) -> dict[str, Any] | None:
    if not len(window_gt):
        return None
    m = metrics.summary(window_pred[None], window_gt[None], start=0)
    return {**m, "n_windows": m["n_pairs"]}


@dataclass(frozen=True)
class RealInputs:
    """The files an ``evaluate-real`` run reads and writes (see :func:`run_real_evaluation`)."""

    recording: Path
    out_dir: Path
    gyro: Path | None = None
    calib: Path | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    checkpoint: Path = DEFAULT_CHECKPOINT
    imu_to_camera: str | None = None
    mean_data: Path | None = None
    sensor: tuple[int, int] | None = None


@dataclass
class RealPlan:
    """A checked ``evaluate-real`` run, before any model runs.

    Attributes:
        offset_ms: the ``--gyro-offset`` to apply, ms (None: the fitted one).
        rotation: IMU-to-camera rotation (None: the gyro is in the camera frame).
        calib_label: where the calibration comes from, for metrics.json (None: none).
        events: the events of the span, on the sensor's pixels.
        camera: CMax's camera (the calibration, or intrinsics from the file's attributes).
        raw_gyro: the gyro in the camera frame, before the clock offset.
        t0, steps: the span starts at ``t0`` µs and has ``steps`` 1 ms steps.
        ends: each step's end, µs (steps,).
        w_starts, w_ends: the user's windows, µs.
        warnings: what the run will report, in order.
    """

    inputs: RealInputs
    config: RealEvalConfig
    offset_ms: float | None
    rotation: np.ndarray | None
    calibration: Calibration | None
    calib_label: str | None
    events: EventArray
    camera: Any
    raw_gyro: GyroTrace
    gyro_source: str
    t0: int
    steps: int
    ends: np.ndarray
    w_starts: np.ndarray
    w_ends: np.ndarray
    warnings: list[str] = field(default_factory=list)

    @property
    def scored_from_us(self) -> int:
        """Time of the end of the warm-up, µs: the first scored step starts here."""
        return self.t0 + self.config.warmup_ms * BIN_US

    @property
    def window_events(self) -> np.ndarray:
        """Number of events in each of the user's windows."""
        t = self.events.t
        return np.searchsorted(t, self.w_ends) - np.searchsorted(t, self.w_starts)


@dataclass
class RealPredictions:
    """What the models answered.

    Attributes:
        per_ms: display name -> (method, omega per step (steps, 3) rad/s) of SNN-6, CMax and
            the mean predictor, in that order.
        payload: the SNN checkpoint's payload.
        cmax_window: CMax's one estimate from each user window's events, (n, 3) rad/s.
        offset_starts, offset_ends, offset_omega: CMax over short windows for the clock
            offset fit (µs, µs, rad/s).
        mean_omega, mean_source: the mean predictor's answer (3,) rad/s and where it is from.
    """

    per_ms: dict[str, tuple[str, np.ndarray]]
    payload: dict[str, Any]
    cmax_window: np.ndarray
    offset_starts: np.ndarray
    offset_ends: np.ndarray
    offset_omega: np.ndarray
    mean_omega: np.ndarray
    mean_source: str


@dataclass
class GyroReference:
    """The gyro as the reference: the offset fit, the shifted trace, its value at each step's
    end (``gt``, rad/s), which steps are scored, and its mean over each scored window."""

    fit: dict[str, Any]
    applied_us: float
    trace: GyroTrace
    gt: np.ndarray
    scored: np.ndarray
    win_ok: np.ndarray
    w_gt: np.ndarray


def _check_config(config: RealEvalConfig) -> None:
    if (config.windows_ms is None) == (config.windows_events is None):
        raise InputError("give one of --windows-ms MS and --windows-events N.")
    if config.end_s is not None and config.end_s <= config.start_s:
        raise InputError(f"--end {config.end_s} s must be after --start {config.start_s} s.")
    if config.start_s < 0 or config.warmup_ms < 0:
        raise InputError("--start and --warmup-ms must not be negative.")


def _span(t_us: np.ndarray, config: RealEvalConfig) -> tuple[int, int]:
    """``(t0, steps)``: the span's start, µs (``--start`` after the first event's whole ms),
    and its length in 1 ms steps (to ``--end`` or past the last event)."""
    t_first = int(t_us[0]) // BIN_US * BIN_US
    t0 = t_first + round(config.start_s * 1e6)
    t_end = int(t_us[-1]) + 1 if config.end_s is None else t_first + round(config.end_s * 1e6)
    return t0, -(-(t_end - t0) // BIN_US)


def _user_windows(
    events: EventArray, config: RealEvalConfig, begin_us: int, end_us: int, recording: Path
) -> tuple[np.ndarray, np.ndarray]:
    """The user's windows tiling ``[begin_us, end_us)``; InputError when none fits."""
    if config.windows_events is not None:
        starts, ends = event_windows(events.t, begin_us, end_us, config.windows_events)
        size = f"{config.windows_events:,} events"
    else:
        starts, ends = time_windows(begin_us, end_us, config.windows_ms * 1000)
        size = f"{config.windows_ms:g} ms"
    if not len(starts):
        raise InputError(
            f"{recording}: no whole window of {size} after the {config.warmup_ms} ms warm-up; "
            "choose smaller windows, a shorter --warmup-ms or a longer span."
        )
    return starts, ends


def plan_real_evaluation(inputs: RealInputs, config: RealEvalConfig) -> RealPlan:
    """Check every input and read the recording and the gyro; no model runs, nothing is written.

    Raises:
        InputError: on bad options, unreadable files, a span without events or windows, or a
            gyro that cannot overlap the scored span.
    """
    recording = inputs.recording
    check_output_dir(inputs.out_dir)
    resolve_checkpoint(inputs.checkpoint)
    _check_config(config)
    offset_ms = parse_gyro_offset(config.gyro_offset)
    rotation = None if inputs.imu_to_camera is None else imu_rotation(inputs.imu_to_camera)
    calibration, calib_file = resolve_calibration(recording, inputs.calib, inputs.intrinsics)
    rec = read_recording(recording, sensor=inputs.sensor)
    if not len(rec.events):
        raise InputError(f"{recording}: the file holds no events.")
    raw_gyro, gyro_source = _load_gyro(rec.gyro, inputs.gyro, rotation)
    t0, steps = _span(rec.events.t, config)
    events = rec.events.slice_time(t0, t0 + steps * BIN_US)
    if not len(events) or steps <= config.warmup_ms:
        raise InputError(
            f"{recording}: {len(events):,} events in {steps} ms between --start and --end; the "
            f"span must be longer than the {config.warmup_ms} ms warm-up."
        )
    ends = t0 + BIN_US * np.arange(1, steps + 1, dtype=np.int64)
    begin = t0 + config.warmup_ms * BIN_US
    _check_overlap(raw_gyro, offset_ms, config, begin, ends[-1], gyro_source)
    # CMax undistorts each event to its ray itself: it takes the raw events and the calibration.
    camera = calibration or camera_from_attrs(rec.attrs, *events.sensor_size)
    w_starts, w_ends = _user_windows(events, config, begin, t0 + steps * BIN_US, recording)
    calib_label = str(calib_file) if calib_file else ("--intrinsics" if inputs.intrinsics else None)
    return RealPlan(
        inputs,
        config,
        offset_ms,
        rotation,
        calibration,
        calib_label,
        events,
        camera,
        raw_gyro,
        gyro_source,
        t0,
        steps,
        ends,
        w_starts,
        w_ends,
    )


def _mean_predictor(mean_data: Path | None) -> tuple[np.ndarray, str]:
    if mean_data is None:
        return np.zeros(3), "zero"
    return training_mean_omega(mean_data, "train"), f"{mean_data}/train"


def predict_real(plan: RealPlan, console: Console) -> RealPredictions:
    """Run SNN-6 and CMax (per ms, per user window, and over short windows for the clock
    offset fit) over the plan's span; the mean predictor's answer comes first (it may fail)."""
    mean_omega, mean_source = _mean_predictor(plan.inputs.mean_data)
    events, camera, config, t0 = plan.events, plan.camera, CMaxConfig(), plan.t0
    offset_cfg = plan.config.offset
    window_us = round(offset_cfg.window_ms * 1000)
    off_ends = np.arange(
        t0 + window_us, t0 + plan.steps * BIN_US + 1, offset_cfg.stride_ms * BIN_US
    )
    with Progress(console=console, transient=True) as bar:

        def tracker(label: str) -> Any:
            task = bar.add_task(label, total=None)
            return lambda done, total: bar.update(task, completed=done, total=total)

        snn, payload = _snn_per_ms(
            events,
            plan.inputs.checkpoint,
            plan.calibration,
            t0,
            plan.steps,
            str(plan.inputs.recording),
            tracker("SNN-6"),
            (plan.config.clock, plan.config.pixels),
        )
        offline = estimate_offline(events, camera, t0_us=t0, progress=tracker("CMax, offline"))
        cmax_ms = cmax_series.per_ms(offline.t_us, offline.omega, plan.ends)
        t_live, w_live = cmax_series.predict_stream(
            events, camera, config, progress=tracker("CMax, live")
        )
        live_ms = cmax_series.per_ms(t_live, w_live, plan.ends)
        cmax_win = _cmax_windows(
            events, camera, config, plan.w_starts, plan.w_ends, tracker("CMax per window")
        )
        # Independent windows: a warm-started stream lags fast changes (by ~2 ms at a 5 ms
        # stride on simulated data), which would bias the offset.
        w_off = _cmax_windows(
            events,
            camera,
            config,
            off_ends - window_us,
            off_ends,
            tracker("CMax for the clock offset"),
        )
    mean_ms = np.broadcast_to(mean_omega, (plan.steps, 3)).copy()
    per_ms = {
        display_name(payload): ("snn", snn),
        "CMax": ("cmax", cmax_ms),
        "CMax (live)": ("cmax_live", live_ms),
        "Mean": ("mean", mean_ms),
    }
    return RealPredictions(
        per_ms, payload, cmax_win, off_ends - window_us, off_ends, w_off, mean_omega, mean_source
    )


def _offset_warnings(fit: dict[str, Any], offset: OffsetConfig) -> list[str]:
    if fit["offset_us"] is None:
        return [f"no clock offset could be fitted: {fit['reason']}"]
    if fit["correlation"] < MIN_OFFSET_CORRELATION:
        return [
            f"the estimates and the gyro hardly correlate at any offset (at best "
            f"{fit['correlation']:.2f}): the motion does not vary enough for CMax over "
            f"{offset.window_ms:g} ms to pin the clock offset down; do not apply it."
        ]
    if fit.get("at_edge"):
        return [
            f"the best clock offset lies at the edge of ±{offset.max_offset_ms:g} ms; the "
            "true one may lie outside."
        ]
    return []


def fit_reference(plan: RealPlan, predicted: RealPredictions) -> GyroReference:
    """Fit the clock offset, apply the chosen one and sample the gyro at every step's end and
    over every window; warnings go to the plan.

    Raises:
        InputError: when no step after the warm-up lies within the shifted gyro's span.
    """
    offset_cfg, warnings = plan.config.offset, plan.warnings
    samples = event_sample_times(plan.events.t, predicted.offset_starts, predicted.offset_ends)
    fit = fit_time_offset(
        samples,
        predicted.offset_omega,
        plan.raw_gyro,
        max_offset_us=offset_cfg.max_offset_ms * 1000,
        step_us=offset_cfg.step_ms * 1000,
    )
    warnings += _offset_warnings(fit, offset_cfg)
    if plan.offset_ms is not None:
        applied_us = plan.offset_ms * 1000
    elif fit["offset_us"] is not None:
        applied_us = fit["offset_us"]
    else:
        applied_us = 0.0
        warnings.append("--gyro-offset auto: no fit, so no offset is applied.")
    trace = shift_gyro(plan.raw_gyro, applied_us)
    warmup, ends = plan.config.warmup_ms, plan.ends
    scored = (np.arange(plan.steps) >= warmup) & covers(trace, ends)
    if not scored.any():
        raise InputError(
            f"{plan.gyro_source}: the gyro ({trace.t[0] / 1e6:.6f} to {trace.t[-1] / 1e6:.6f} s) "
            f"does not cover the scored span ({plan.scored_from_us / 1e6:.6f} to "
            f"{ends[-1] / 1e6:.6f} s on the events' clock)."
        )
    if (outside := int((~scored[warmup:]).sum())) > 0:
        warnings.append(
            f"{outside} steps after the warm-up lie outside the gyro's span and are not scored."
        )
    win_ok = covers(trace, plan.w_starts) & covers(trace, plan.w_ends)
    if not win_ok.all():
        warnings.append(f"{int((~win_ok).sum())} windows lie outside the gyro's span; left out.")
    w_gt = window_means(trace, plan.w_starts, plan.w_ends)
    return GyroReference(fit, applied_us, trace, trace.interpolate(ends), scored, win_ok, w_gt)


def _score_models(
    plan: RealPlan, predicted: RealPredictions, ref: GyroReference
) -> tuple[dict[str, dict[str, Any]], dict[str, np.ndarray]]:
    """Each model's per-ms and per-window metrics, and its mean over each window (rad/s)."""
    models: dict[str, dict[str, Any]] = {}
    window_pred: dict[str, np.ndarray] = {}
    for name, (method, series) in predicted.per_ms.items():
        models[name] = _method_results(
            name, method, series, ref.gt, ref.scored, plan.config.speed_bins
        )
        window_pred[name] = bin_means(series, plan.t0, plan.w_starts, plan.w_ends)
    window_pred["CMax (window)"] = predicted.cmax_window
    models["CMax (window)"] = {"name": "CMax (window)", "method": "cmax_window", "metrics": None}
    for name, pred in window_pred.items():
        models[name]["window_metrics"] = _window_results(pred[ref.win_ok], ref.w_gt[ref.win_ok])
    snn_name = next(iter(predicted.per_ms))
    models[snn_name]["source"] = str(plan.inputs.checkpoint)
    models["Mean"]["omega_rad_s"] = predicted.mean_omega.tolist()
    models["Mean"]["source"] = predicted.mean_source
    return models, window_pred


def _data_json(plan: RealPlan, ref: GyroReference) -> dict[str, Any]:
    config, events, w_starts, w_ends = plan.config, plan.events, plan.w_starts, plan.w_ends
    by_events = config.windows_events is not None
    return {
        "recording": str(plan.inputs.recording),
        "calibration": plan.calib_label,
        "sensor": list(events.sensor_size),
        "t0_s": plan.t0 / 1e6,
        "steps_ms": plan.steps,
        "events": len(events),
        "event_rate_per_s": len(events) / (plan.steps / 1000),
        "warmup_ms": config.warmup_ms,
        "scored_steps": int(ref.scored.sum()),
        "windows": {
            "by": "events" if by_events else "time",
            "size": config.windows_events if by_events else config.windows_ms,
            "count": len(w_starts),
            "scored": int(ref.win_ok.sum()),
            "start_s": (w_starts / 1e6).tolist(),
            "end_s": (w_ends / 1e6).tolist(),
            "events": plan.window_events.tolist(),
        },
    }


def _gyro_json(plan: RealPlan, ref: GyroReference) -> dict[str, Any]:
    raw = plan.raw_gyro
    return {
        "source": plan.gyro_source,
        "samples": len(raw),
        "span_s": [raw.t[0] / 1e6, raw.t[-1] / 1e6],
        "sampling_interval": sampling_interval_us(raw),
        "imu_to_camera": None if plan.rotation is None else plan.rotation.tolist(),
        "offset_fit": ref.fit,
        "offset_applied_us": float(ref.applied_us),
        "offset_convention": "added to the gyro's timestamps: gyro(t - offset) is the "
        "reference at event time t",
    }


@dataclass
class RealScores:
    """The scores: ``result`` (what metrics.json holds) and each model's mean over each user
    window (rad/s, (n, 3), for windows.csv and the figures)."""

    result: dict[str, Any]
    window_pred: dict[str, np.ndarray]


def score_real(plan: RealPlan, predicted: RealPredictions, ref: GyroReference) -> RealScores:
    """Score every model against the gyro per ms and per window (:mod:`.metrics`)."""
    models, window_pred = _score_models(plan, predicted, ref)
    snn_name = next(iter(predicted.per_ms))
    if empty := empty_bins(models[snn_name]["per_bin"]):
        plan.warnings.append(
            f"no scored step in speed bin(s) {', '.join(empty)} deg/s; left empty."
        )
    result = {
        "format": REAL_METRICS_FORMAT,
        "data": _data_json(plan, ref),
        "gyro": _gyro_json(plan, ref),
        "bins": bins_json(plan.config.speed_bins),
        "models": models,
        "windows_omega_rad_s": {
            "gyro": ref.w_gt.tolist(),
            **{name: pred.tolist() for name, pred in window_pred.items()},
        },
        "warnings": plan.warnings,
    }
    return RealScores(result, window_pred)


def write_real(
    plan: RealPlan, predicted: RealPredictions, ref: GyroReference, scores: RealScores
) -> None:
    """Write every output into the plan's folder at once (all or nothing)."""
    result, window_pred = scores.result, scores.window_pred
    with atomic_dir(plan.inputs.out_dir) as staging:
        write_tables(
            staging,
            plan.ends,
            ref.scored,
            ref.gt,
            predicted.per_ms,
            plan.w_starts,
            plan.w_ends,
            plan.window_events,
            ref.win_ok,
            ref.w_gt,
            window_pred,
        )
        write_json(staging / "metrics.json", result)
        write_figures(
            staging,
            result,
            plan.t0,
            plan.ends,
            predicted.per_ms,
            ref.trace,
            plan.w_starts,
            plan.w_ends,
            predicted.cmax_window,
        )
        write_real_report(staging, result)


def _print_real_summary(
    plan: RealPlan, ref: GyroReference, result: dict[str, Any], console: Console
) -> None:
    models, fit = result["models"], ref.fit
    console_rows = [m for m in models.values() if m["metrics"] is not None]
    print_summary(
        console,
        f"{plan.inputs.recording}: {int(ref.scored.sum())} steps, {int(ref.win_ok.sum())} windows",
        [*console_rows, models["CMax (window)"] | {"metrics": {}}],
        plan.warnings,
        window_label="per window",
        start_ms=plan.config.warmup_ms,
    )
    if fit["offset_us"] is not None:
        console.print(
            f"gyro sampled every {result['gyro']['sampling_interval']['median_us'] / 1000:.3f} "
            f"ms; best clock offset {fit['offset_us'] / 1000:+.2f} ms (correlation "
            f"{fit['correlation']:.3f}), applied {ref.applied_us / 1000:+.2f} ms"
        )
    console.print(
        f"wrote {plan.inputs.out_dir}/metrics.json, predictions.csv, windows.csv, report.html"
    )


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
    """Score SNN-6, CMax and the mean predictor against a gyro on a real recording: plan
    (:func:`plan_real_evaluation`), predict (:func:`predict_real`), score
    (:func:`fit_reference`, :func:`score_real`) and write (:func:`write_real`).

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
    console = console or Console(stderr=True)

    def path(value: str | os.PathLike | None) -> Path | None:
        return None if value is None or value == "" else Path(value)

    inputs = RealInputs(
        Path(recording),
        Path(out_dir),
        path(gyro),
        path(calib),
        intrinsics,
        path(checkpoint) or DEFAULT_CHECKPOINT,
        imu_to_camera,
        path(mean_data),
        sensor,
    )
    plan = plan_real_evaluation(inputs, config or RealEvalConfig())
    predicted = predict_real(plan, console)
    reference = fit_reference(plan, predicted)
    scores = score_real(plan, predicted, reference)
    write_real(plan, predicted, reference, scores)
    _print_real_summary(plan, reference, scores.result, console)
    return scores.result
