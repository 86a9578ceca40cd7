"""Streaming prediction from an event file: any estimator, metrics against a gyro, flat memory.

The pipeline never holds more than one chunk of events: ``iter_event_chunks`` -> a
:class:`~spikegyro.stream.estimator.GyroEstimator` (``update`` per chunk, ``finish`` at the end)
-> prediction writer, each estimate scored against the gyro interpolated at its time. Two
estimators: contrast maximization (``spikegyro.cmax.live.CMaxEstimator``: causal
adaptive windows at a fixed rate, the one for real cameras) and the network
(:class:`SNNEstimator`: reproject onto the model's camera -> split into completed 1 ms bins ->
:class:`StreamingSNN`, or anything with ``push``/``finish`` (a :class:`Predictor`), such as the
batched torch path of :mod:`spikegyro.stream.batched`).
Memory is flat in the length of the recording (the plot keeps a decimated copy of at most
``_PLOT_POINTS`` samples; the median relative error and the latency come from histograms).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from spikegyro import metrics
from spikegyro.errors import InputError, check_interrupt
from spikegyro.events.calib import Calibration, PinholeCamera
from spikegyro.events.clock import Clock
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.events.io import (
    detect_format,
    iter_event_chunks,
    open_hdf5,
    read_gyro,
    read_hdf5_attrs,
)
from spikegyro.events.windows import BIN_US
from spikegyro.stream.clocked import ClockedPredictor, RowHolder
from spikegyro.stream.estimator import (
    ILL_FEW_EVENTS,
    ILL_LITTLE_MOTION,
    ILL_NOT_ONE_ROTATION,
    Estimates,
    GyroEstimator,
)
from spikegyro.stream.stateful import StreamingSNN
from spikegyro.stream.writer import PredictionWriter, write_predictions

__all__ = [
    "ErrorStats",
    "Predictor",
    "PredictorFactory",
    "SNNEstimator",
    "StreamPredictor",
    "check_span",
    "event_mapper",
    "model_camera",
    "predict_stream",
    "read_time_span",
    "span_seconds",
    "write_predictions",
]

WARMUP_STEPS = 50
"""Steps after the start that metrics skip: the network needs ~50 ms of history (as in training)."""
_PLOT_POINTS = 20_000


def model_camera(input_spec: dict[str, Any]) -> PinholeCamera:
    """The pinhole camera the model's input pixels correspond to.

    ``input_spec["sensor"]`` is the training sensor [width, height]; its intrinsics are
    ``input_spec["intrinsics"]`` [fx, fy, cx, cy] when given, else f = 200 px with the principal
    point at the image centre (the simulator's default); ``scale`` resizes the image.
    """
    width, height = (int(v) for v in input_spec.get("sensor", (240, 180)))
    fx, fy, cx, cy = input_spec.get("intrinsics", (200.0, 200.0, width / 2, height / 2))
    camera = PinholeCamera(width, height, float(fx), float(fy), float(cx), float(cy))
    return camera.scaled(float(input_spec.get("scale", 1.0)))


def event_mapper(
    sensor: tuple[int, int],
    input_spec: dict[str, Any],
    calibration: Calibration | None,
    source: str = "events",
) -> Callable[[EventArray], EventArray]:
    """A function taking sensor events to events on the model's input grid.

    With a calibration, every sensor pixel is undistorted and reprojected onto the model's camera
    (lookup table), unless the model reads the sensor's own pixels (``input_spec["pixels"]``
    is ``"sensor"``: :func:`sensor_window`). Without one the sensor must be the model's
    training sensor; the events are then resized by the model's ``scale`` exactly as in
    training.
    """
    target = model_camera(input_spec)
    if calibration is not None and input_spec.get("pixels") == "sensor":
        return sensor_window(sensor, target, calibration)
    if calibration is not None:
        calibration.lookup_table(sensor[0], sensor[1], target)  # build (and check) it once
        return lambda ev: calibration.map_events(ev, target)
    trained = tuple(int(v) for v in input_spec.get("sensor", (240, 180)))
    if tuple(sensor) != trained:
        raise InputError(
            f"{source}: sensor is {sensor[0]}x{sensor[1]} but the model was trained on "
            f"{trained[0]}x{trained[1]}; pass --calib FILE or --intrinsics fx fy cx cy so the "
            "events can be reprojected onto the model's camera."
        )
    scale = float(input_spec.get("scale", 1.0))
    return (lambda ev: ev) if scale == 1.0 else (lambda ev: ev.rescale(scale))


def sensor_window(
    sensor: tuple[int, int], target: PinholeCamera, calibration: Calibration
) -> Callable[[EventArray], EventArray]:
    """The sensor's own pixels, not resampled: a window of the model's size whose centre is the
    principal point (cropped, or padded where the sensor is smaller; lens distortion is kept).
    Rounding events onto another grid costs accuracy; :func:`output_gain` corrects the focal
    length at the output instead."""
    dx = round(calibration.cx - target.cx)
    dy = round(calibration.cy - target.cy)
    width, height = target.width, target.height

    def window(ev: EventArray) -> EventArray:
        x, y = ev.x.astype(np.int64) - dx, ev.y.astype(np.int64) - dy
        keep = (x >= 0) & (x < width) & (y >= 0) & (y < height)
        return EventArray(x[keep].astype(np.int16), y[keep].astype(np.int16), ev.t[keep],
                          ev.p[keep], width, height)  # fmt: skip

    del sensor  # any size: the window is cut around the principal point
    return window


def output_gain(input_spec: dict[str, Any], calibration: Calibration | None) -> np.ndarray:
    """(3,) factor on the network's ω for a model reading the sensor's own pixels: a tilt or pan
    moves an edge by f·ω pixels, so a sensor of focal length f reads as f / f_model times the
    rate (roll, whose flow is ω·r, needs none); ones otherwise."""
    if calibration is None or input_spec.get("pixels") != "sensor":
        return np.ones(3)
    return focal_gain(input_spec, calibration)


def focal_gain(input_spec: dict[str, Any], camera: Any) -> np.ndarray:
    """(3,) ``[f_model / f_y, f_model / f_x, 1]``: from the ω a network reads in ``camera``'s own
    pixels (``fx``, ``fy``, pixels) to the true ω (see :func:`output_gain`)."""
    target = model_camera(input_spec)
    return np.array([target.fy / camera.fy, target.fx / camera.fx, 1.0])


class Predictor(Protocol):
    """Turns time-ordered events on the model's grid into ω per 1 ms bin since ``t0_us``.

    ``push`` and ``finish`` return (t_us, ω rad/s) of the bins they completed, in order, each
    bin once, stamped at the bin's end; ``steps`` counts the bins returned so far; ``label``
    names the engine in summaries.
    """

    steps: int
    label: str

    def push(self, events: EventArray) -> tuple[np.ndarray, np.ndarray]: ...

    def finish(self, t_end_us: int) -> tuple[np.ndarray, np.ndarray]: ...


PredictorFactory = Callable[[PinholeCamera, int], Predictor]
"""Builds a fresh :class:`Predictor` for the model's camera and the first bin's start (µs)."""


class StreamPredictor:
    """Feed time-ordered events (already on the model's grid); get ω for every completed 1 ms bin.

    Bin k covers ``[t0_us + k ms, t0_us + (k+1) ms)``; its prediction is stamped at the end of the
    bin, ``t0_us + (k+1) ms``, like the ground truth in training.
    """

    def __init__(self, engine: StreamingSNN, width: int, t0_us: int) -> None:
        self.engine = engine
        threads = "thread" if engine.threads == 1 else "threads"
        self.label = f"event-driven stream (exact; CPU, {engine.threads} {threads})"
        self.width = width
        self.t0_us = int(t0_us)
        self.steps = 0
        self._pending: list[EventArray] = []

    def push(self, events: EventArray) -> tuple[np.ndarray, np.ndarray]:
        """Add events; returns (t_us, omega rad/s) of the bins completed so far."""
        if not len(events):
            return np.zeros(0, np.int64), np.zeros((0, 3))
        # a bin is complete once an event at or after its end has been seen
        complete = int(events.t[-1] - self.t0_us) // BIN_US
        self._pending.append(events)
        return self._advance(complete)

    def finish(self, t_end_us: int) -> tuple[np.ndarray, np.ndarray]:
        """Run the remaining bins up to the one holding ``t_end_us - 1`` (the end, exclusive)."""
        return self._advance(-(-(int(t_end_us) - self.t0_us) // BIN_US))

    def _advance(self, n_total: int) -> tuple[np.ndarray, np.ndarray]:
        n = n_total - self.steps
        if n <= 0:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        index, offsets = np.zeros(0, np.int64), np.zeros(n + 1, np.int64)  # bins without events
        if self._pending:
            ev = EventArray.concatenate(self._pending)
            cut = int(np.searchsorted(ev.t, self.t0_us + n_total * BIN_US, side="left"))
            now, rest = ev[:cut], ev[cut:]
            self._pending = [rest] if len(rest) else []
            k = (now.t - self.t0_us) // BIN_US - self.steps
            offsets = np.searchsorted(k, np.arange(n + 1), side="left")
            index = (now.y.astype(np.int64) * self.width + now.x) * 2 + now.p
        omega = self.engine.run(index, offsets)
        t_us = self.t0_us + (self.steps + 1 + np.arange(n, dtype=np.int64)) * BIN_US
        self.steps = n_total
        return t_us, omega


PIXELS = ("sensor", "model")
"""How a calibrated sensor's events reach the network: its own pixels (a window around the
principal point, the focal length corrected at the output) or reprojected onto the model's
camera."""


def spec_with(
    input_spec: dict[str, Any], clock: str | None = None, pixels: str | None = None
) -> dict[str, Any]:
    """A checkpoint's input description with the network run on ``clock`` (``--clock`` text,
    :meth:`Clock.parse`) and reading ``pixels`` (:data:`PIXELS`) instead of its own; None
    keeps the checkpoint's."""
    spec = dict(input_spec)
    if pixels is not None:
        if pixels not in PIXELS:
            raise InputError(f"--pixels {pixels}: choose 'sensor' or 'model'.")
        spec["pixels"] = pixels
    if clock is None:
        return spec
    steps = Clock.parse(clock)
    spec = {k: v for k, v in spec.items() if k != "clock"}
    return spec if steps.is_paper else {**spec, "clock": steps.as_dict()}


def clocked_predictor(
    engine: StreamingSNN | PredictorFactory, input_spec: dict[str, Any], t0_us: int
) -> Predictor | ClockedPredictor:
    """A fresh predictor for a stream starting at ``t0_us``: 1 ms bins from there, or, for a
    model on the event clock (``input_spec["clock"]``), its steps (real ends, rad/s)."""
    target = model_camera(input_spec)
    clock = Clock.from_dict(input_spec.get("clock"))
    start = t0_us if clock.is_paper else 0
    if isinstance(engine, StreamingSNN):
        engine.reset()
        inner: Predictor = StreamPredictor(engine, target.width, start)
    else:
        inner = engine(target, start)
    return inner if clock.is_paper else ClockedPredictor(inner, clock, t0_us)


class SNNEstimator:
    """The spiking network as a :class:`~spikegyro.stream.estimator.GyroEstimator`: one
    estimate per 1 ms bin, stamped at the bin's end (it uses the events before it).

    Args:
        engine: the stateful network (:class:`StreamingSNN`), or a :data:`PredictorFactory`
            (e.g. the batched torch path).
        input_spec: the checkpoint's input description (sensor, scale, intrinsics).
        calibration: the sensor's calibration; None when the sensor is the model's own.
        rate_hz: keep one bin in ``1000 / rate_hz`` (a divisor of 1000); None or 1000: all.
        source: the events' name in error messages.
    """

    def __init__(
        self,
        engine: StreamingSNN | PredictorFactory,
        input_spec: dict[str, Any] | None = None,
        calibration: Calibration | None = None,
        rate_hz: float | None = None,
        source: str = "events",
    ) -> None:
        self.engine, self.input_spec = engine, dict(input_spec or {})
        self.calibration, self.source = calibration, source
        every = 1 if rate_hz is None else 1000.0 / rate_hz
        if every < 1 or abs(every - round(every)) > 1e-9:
            raise InputError(
                f"--rate-hz {rate_hz:g}: the SNN answers every 1 ms; use a divisor of 1000 Hz."
            )
        self.every = round(every)
        self.label = "SNN"
        self.confidence = False
        self.reset()

    def reset(self, t0_us: int | None = None) -> None:
        """Start a new stream with bins from ``t0_us`` (None: the first event's millisecond)."""
        self.t0_us = t0_us
        self._predictor: Predictor | None = None
        self._mapper: Callable[[EventArray], EventArray] | None = None

    @property
    def clocked(self) -> bool:
        """Whether the network runs on the event clock (rows hold its latest step)."""
        return not Clock.from_dict(self.input_spec.get("clock")).is_paper

    @property
    def steps(self) -> int:
        """Steps run so far."""
        return 0 if self._predictor is None else self._predictor.steps

    def update(self, events: EventArray) -> Estimates:
        """Run the bins the batch completes."""
        if not len(events):
            return Estimates.empty()
        if self._predictor is None:
            self._start(events)
        return self._keep(*self._predictor.push(self._mapper(events)))

    def finish(self, t_end_us: int) -> Estimates:
        """Run the bins up to the one holding ``t_end_us - 1``."""
        if self._predictor is None:
            return Estimates.empty()
        return self._keep(*self._predictor.finish(t_end_us))

    def _start(self, events: EventArray) -> None:
        if self.t0_us is None:
            self.t0_us = int(events.t[0]) // BIN_US * BIN_US
        self._predictor = clocked_predictor(self.engine, self.input_spec, self.t0_us)
        if isinstance(self._predictor, ClockedPredictor):
            self._holder = RowHolder(self.t0_us, self.every * BIN_US)
        self.label = self._predictor.label
        self._mapper = event_mapper(
            events.sensor_size, self.input_spec, self.calibration, self.source
        )
        self._gain = output_gain(self.input_spec, self.calibration)

    def _keep(self, t_us: np.ndarray, omega: np.ndarray) -> Estimates:
        omega = omega * self._gain
        predictor = self._predictor
        if isinstance(predictor, ClockedPredictor):
            return self._holder.rows(
                t_us, omega, predictor.step_us, predictor.counts, predictor.settled_us
            )
        if self.every > 1:
            keep = (t_us - self.t0_us) % (self.every * BIN_US) == 0
            t_us, omega = t_us[keep], omega[keep]
        return Estimates(t_us, omega)


@dataclass
class ErrorStats:
    """Running error statistics of predictions against a reference, in bounded memory.

    Each estimate's errors are those of :mod:`spikegyro.metrics` (the rows taken as
    one window whose every step is scored); their sums (deg/s) give the means, and a histogram
    of log10 relative errors (0.1 % bins) gives the median.
    """

    count: int = 0
    sum_err: float = 0.0
    sum_sq: float = 0.0
    sum_sq_axis: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sum_abs_axis: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hist: np.ndarray = field(default_factory=lambda: np.zeros(8002, dtype=np.int64))

    def add(self, omega: np.ndarray, reference: np.ndarray) -> None:
        """Accumulate (K, 3) predictions and references, rad/s; NaN reference rows are skipped."""
        ok = np.isfinite(reference).all(axis=1)
        if not ok.any():
            return
        pred, ref = omega[None, ok], reference[None, ok]
        err = metrics.euclidean_errors_deg(pred, ref, start=0)
        p, g = metrics.evaluated_steps(pred, ref, start=0)
        axis_err = np.degrees(p - g).reshape(-1, 3)
        self.count += err.size
        self.sum_err += float(err.sum())
        self.sum_sq += float((err**2).sum())
        self.sum_sq_axis += (axis_err**2).sum(axis=0)
        self.sum_abs_axis += np.abs(axis_err).sum(axis=0)
        rel = np.log10(np.maximum(metrics.relative_errors(pred, ref, start=0), 1e-30))
        bins = np.clip(np.floor((rel + 4.0) * 1000).astype(np.int64) + 1, 0, len(self.hist) - 1)
        self.hist += np.bincount(bins, minlength=len(self.hist))

    def summary(self) -> dict[str, float]:
        """Mean Euclidean error, RMSE, per-axis RMSE and mean absolute error (deg/s), and the
        median relative error."""
        if not self.count:
            return {}
        cum = np.cumsum(self.hist)
        if cum[-1]:
            i = int(np.searchsorted(cum, (cum[-1] + 1) // 2))
            median_rel = 10 ** ((i - 0.5) / 1000 - 4.0)
        else:
            median_rel = float("nan")
        axis_rmse = np.sqrt(self.sum_sq_axis / self.count)
        axis_mae = self.sum_abs_axis / self.count
        return {
            "samples": self.count,
            "mean_error_deg_s": self.sum_err / self.count,
            "rmse_deg_s": math.sqrt(self.sum_sq / self.count),
            **{f"rmse_{k}_deg_s": float(v) for k, v in zip("xyz", axis_rmse, strict=True)},
            **{f"mae_{k}_deg_s": float(v) for k, v in zip("xyz", axis_mae, strict=True)},
            "median_relative_error": float(median_rel),
        }


class _Decimated:
    """Keep every ``stride``-th row, doubling the stride whenever the buffer fills."""

    def __init__(self, limit: int = _PLOT_POINTS) -> None:
        self.limit, self.stride, self.seen = limit, 1, 0
        self.rows: list[np.ndarray] = []
        self.size = 0

    def add(self, table: np.ndarray) -> None:
        keep = (self.seen + np.arange(len(table))) % self.stride == 0
        self.seen += len(table)
        self.rows.append(table[keep])
        self.size += int(keep.sum())
        if self.size > self.limit:
            merged = np.concatenate(self.rows)
            self.stride *= 2
            self.rows = [merged[::2]]
            self.size = len(self.rows[0])

    def table(self) -> np.ndarray:
        return np.concatenate(self.rows) if self.rows else np.zeros((0, 8))


def read_time_span(path: str | os.PathLike) -> tuple[int, int] | None:
    """First and last event time (µs) of a file, read cheaply; None if unknown or empty."""
    path = Path(path)
    kind = detect_format(path)
    if kind == "hdf5":
        with open_hdf5(path) as f:
            ts = f.get("ev_ts")
            return (int(ts[0]), int(ts[-1])) if ts is not None and ts.shape[0] else None
    if kind in ("events_txt", "ecd_dir"):
        text = path / "events.txt" if kind == "ecd_dir" else path
        first = next(iter_event_chunks(text, chunk_events=1), None)
        if first is None or not len(first):
            return None
        with open(text, "rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - 4096))
            lines = [ln for ln in f.read().splitlines() if ln.strip()]
        try:
            last = round(float(lines[-1].split()[0].rstrip(b",")) * 1e6)
        except (ValueError, IndexError):
            return None
        return int(first.t[0]), last
    return None


def check_span(start_s: float, end_s: float | None) -> None:
    """Raise :class:`InputError` unless ``--end`` (s; None: the last event) is after ``--start``."""
    if end_s is not None and end_s <= start_s:
        raise InputError(f"--end {end_s} s must be after --start {start_s} s.")


def span_seconds(path: str | os.PathLike, start_s: float, end_s: float | None) -> float | None:
    """Seconds of events a run of ``path`` from ``start_s`` to ``end_s`` (s after the first event;
    None: to the last) covers, read cheaply; None where the file does not say."""
    span = read_time_span(path)
    if span is None:
        return None
    total_s = max(0.0, (span[1] - span[0]) / 1e6 - start_s)
    return total_s if end_s is None else min(total_s, end_s - start_s)


def _bounded_chunks(
    path: Path,
    sensor: tuple[int, int] | None,
    chunk_events: int,
    start_s: float,
    end_s: float | None,
) -> tuple[int | None, int | None, Iterator[EventArray]]:
    """(t0_us, t_end_us, chunks); start and end count from the first event's whole millisecond."""
    chunks = iter_event_chunks(path, sensor=sensor, chunk_events=chunk_events)
    first = None
    for chunk in chunks:
        if len(chunk):
            first = chunk
            break
    if first is None:
        return None, None, iter(())
    t_first = int(first.t[0]) // BIN_US * BIN_US
    t0 = t_first + round(start_s * 1e6)
    t_end = None if end_s is None else t_first + round(end_s * 1e6)

    def gen() -> Iterator[EventArray]:
        for chunk in _chain(first, chunks):
            if t_end is not None and len(chunk) and chunk.t[0] >= t_end:
                return
            lo = int(np.searchsorted(chunk.t, t0, side="left"))
            hi = len(chunk) if t_end is None else int(np.searchsorted(chunk.t, t_end))
            if hi > lo:
                yield chunk[lo:hi]

    return t0, t_end, gen()


def _chain(first: EventArray, rest: Iterator[EventArray]) -> Iterator[EventArray]:
    yield first
    yield from rest


@dataclass
class StreamResult:
    """What :func:`predict_stream` did.

    Attributes:
        steps: whole milliseconds of events covered (from ``t0_us``).
        estimates: rows written, each its own estimate.
        events: events read.
        wall_s, cpu_s: wall-clock and CPU time of this process, seconds.
        t0_us: start of the output clock, µs.
        engine: the estimator's label.
        stats: error statistics against the gyro (:meth:`ErrorStats.summary`), from
            :data:`WARMUP_STEPS` ms on.
        latency_ms: median of how far each estimate's events lie, on average, before its time
            (NaN where the estimator does not say).
        ill_posed: estimates flagged with too few events, with too little motion, and as not
            explained by one rotation.
        plot: the plot against the gyro, if drawn.
        why_none: where there is no estimate, the estimator's reason (empty: not known).
    """

    steps: int = 0
    estimates: int = 0
    events: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0
    t0_us: int = 0
    engine: str = ""
    stats: dict[str, float] = field(default_factory=dict)
    latency_ms: float = float("nan")
    ill_posed: tuple[int, int, int] = (0, 0, 0)
    plot: Path | None = None
    why_none: str = ""

    @property
    def realtime_factor(self) -> float:
        """Seconds of events processed per second of wall time."""
        return self.steps * BIN_US / 1e6 / self.wall_s if self.wall_s > 0 else float("inf")

    @property
    def cpu_realtime_factor(self) -> float:
        """Seconds of events processed per CPU-second (what one free core would do)."""
        return self.steps * BIN_US / 1e6 / self.cpu_s if self.cpu_s > 0 else float("inf")

    @property
    def rate_hz(self) -> float:
        """Distinct estimates per second of events."""
        return self.estimates / (self.steps * BIN_US / 1e6) if self.steps else 0.0


class _Summary:
    """Running latency median (histogram, 0.1 ms bins) and ill-posed counts."""

    def __init__(self) -> None:
        self.delay_hist = np.zeros(10_001, dtype=np.int64)
        self.few = self.little = self.not_one = 0

    def add(self, est: Estimates) -> None:
        delay = est.delay_us[np.isfinite(est.delay_us)]
        bins = np.clip((delay / 100).astype(np.int64), 0, len(self.delay_hist) - 1)
        self.delay_hist += np.bincount(bins, minlength=len(self.delay_hist))
        self.few += int((est.ill_posed & ILL_FEW_EVENTS).astype(bool).sum())
        self.little += int((est.ill_posed & ILL_LITTLE_MOTION).astype(bool).sum())
        self.not_one += int((est.ill_posed & ILL_NOT_ONE_ROTATION).astype(bool).sum())

    def latency_ms(self) -> float:
        cum = np.cumsum(self.delay_hist)
        if not cum[-1]:
            return float("nan")
        return (int(np.searchsorted(cum, (cum[-1] + 1) // 2)) + 0.5) / 10


def predict_stream(
    events_path: str | os.PathLike,
    engine: StreamingSNN | PredictorFactory | GyroEstimator,
    input_spec: dict[str, Any] | None,
    out_path: str | os.PathLike,
    *,
    calibration: Calibration | None = None,
    gyro_path: str | os.PathLike | None = None,
    gyro_rotation: np.ndarray | None = None,
    sensor: tuple[int, int] | None = None,
    start_s: float = 0.0,
    end_s: float | None = None,
    chunk_events: int = 200_000,
    on_progress: Callable[[float, float], None] | None = None,
    plot: bool = True,
) -> StreamResult:
    """Stream ``events_path`` through an estimator, writing each estimate to ``out_path``.

    Args:
        events_path: any event file :mod:`spikegyro.events.io` reads.
        engine: a :class:`~spikegyro.stream.estimator.GyroEstimator` (e.g.
            ``CMaxEstimator``, :class:`SNNEstimator`; reset here), or the stateful network, or
            a factory of another :class:`Predictor` (both wrapped in :class:`SNNEstimator`).
        input_spec: the checkpoint's input description (sensor, scale, intrinsics), for the
            network; None for other estimators.
        out_path: ``.csv`` or ``.h5`` prediction file (written atomically).
        calibration: the sensor's calibration, for the network (an estimator has its own).
        gyro_path: reference angular velocity (gyro/IMU text, or a file with ground truth),
            interpolated to each estimate's time; adds columns, error statistics and a plot.
        gyro_rotation: R with ω_camera = R · ω_gyro (:func:`spikegyro.events.imu.imu_rotation`)
            when the gyro is not in the camera frame.
        sensor: (width, height) override for files that do not say (text defaults to 240x180).
        start_s, end_s: the time span to run, seconds after the file's first event (rounded down
            to a whole millisecond, so bins align with the simulator's and the gyro's clock).
        on_progress: called as ``on_progress(event_seconds_done, wall_seconds)`` per chunk.
        plot: draw predictions against the gyro beside ``out_path`` (``.png``) when a gyro is given.
    """
    events_path = Path(events_path)
    gyro = None if gyro_path is None else read_gyro(gyro_path, imu_to_camera=gyro_rotation)
    check_span(start_s, end_s)
    estimator = (
        engine
        if isinstance(engine, GyroEstimator)
        else SNNEstimator(engine, input_spec, calibration, source=str(events_path))
    )
    t0, t_end, chunks = _bounded_chunks(events_path, sensor, chunk_events, start_s, end_s)
    if t0 is None:
        raise InputError(f"{events_path}: the file holds no events.")
    estimator.reset(t0)
    run = _StreamRun(gyro, t0)
    confidence = bool(getattr(estimator, "confidence", False))
    steps = bool(getattr(estimator, "clocked", False))
    with PredictionWriter(
        out_path, with_gyro=gyro is not None, with_confidence=confidence, with_steps=steps
    ) as w:
        last_t = t0
        for chunk in chunks:
            check_interrupt()
            run.result.events += len(chunk)
            last_t = int(chunk.t[-1])
            run.emit(w, estimator.update(chunk))
            if on_progress is not None:
                on_progress((last_t - t0) / 1e6, time.perf_counter() - run.started)
        if not run.result.events:
            raise InputError(f"{events_path}: no events between --start and --end.")
        end = t_end if t_end is not None else last_t + 1
        run.emit(w, estimator.finish(end))
    result = run.finish(end, estimator.label)
    result.why_none = getattr(estimator, "why_none", str)()
    if gyro is not None and plot:
        result.plot = plot_against_gyro(
            Path(out_path).with_suffix(".png"), run.series.table(), t0, _short_label(estimator)
        )
    return result


class _StreamRun:
    """The bookkeeping of one :func:`predict_stream` run: rows written, scores against the gyro
    (from :data:`WARMUP_STEPS` ms after ``t0_us``), the plot's samples, latency and timing."""

    def __init__(self, gyro: GyroTrace | None, t0_us: int) -> None:
        self.gyro, self.t0_us = gyro, t0_us
        self.result = StreamResult(t0_us=t0_us)
        self.stats, self.series, self.summary = ErrorStats(), _Decimated(), _Summary()
        self.started, self._cpu = time.perf_counter(), time.process_time()

    def emit(self, writer: PredictionWriter, est: Estimates) -> None:
        """Score ``est`` against the gyro (NaN outside its span) and append it to ``writer``."""
        ref = None
        if self.gyro is not None:
            ref = self.gyro.interpolate(est.t_us)
            span = self.gyro.t
            outside = (est.t_us < span[0]) | (est.t_us > span[-1]) if len(self.gyro) else True
            ref[outside] = np.nan
            scored = est.t_us > self.t0_us + WARMUP_STEPS * BIN_US
            self.stats.add(est.omega[scored], ref[scored])
            self.series.add(np.column_stack([est.t_us, est.omega, ref, est.ill_posed]))
        self.summary.add(est)
        self.result.estimates += len(est)
        writer.append(est.t_us, est.omega, ref, est if writer.with_confidence else None)

    def finish(self, end_us: int, engine: str) -> StreamResult:
        """The result of a run that covered events up to ``end_us`` (exclusive)."""
        result = self.result
        result.wall_s = time.perf_counter() - self.started
        result.cpu_s = time.process_time() - self._cpu
        result.steps = -(-(end_us - self.t0_us) // BIN_US)
        result.engine = engine
        result.stats = self.stats.summary()
        result.latency_ms = self.summary.latency_ms()
        result.ill_posed = (self.summary.few, self.summary.little, self.summary.not_one)
        return result


def _short_label(estimator: Any) -> str:
    """The method's name on plots: ``CMax`` or ``SNN``."""
    return "CMax" if "contrast" in str(getattr(estimator, "label", "")) else "SNN"


def plot_against_gyro(path: Path, table: np.ndarray, t0_us: int, label: str = "SNN") -> Path:
    """Predicted and reference ω per axis (deg/s) over time; ``table`` rows: t_us, ω(3), ref(3)
    and optionally the ``ill_posed`` bits, whose estimates not explained by one rotation (bit 4)
    are marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spikegyro.events.io import atomic_path

    t = (table[:, 0] - t0_us) / 1e6
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 6.5))
    for k, (ax, name) in enumerate(
        zip(axes, ("ω_x (tilt)", "ω_y (pan)", "ω_z (roll)"), strict=True)
    ):
        ax.plot(t, np.degrees(table[:, 4 + k]), color="0.3", lw=1.0, label="gyro")
        ax.plot(t, np.degrees(table[:, 1 + k]), color="C3", lw=0.8, label=label)
        if table.shape[1] > 7:
            odd = (table[:, 7].astype(np.int64) & ILL_NOT_ONE_ROTATION) > 0
            if odd.any():
                ax.plot(
                    t[odd], np.degrees(table[odd, 1 + k]), "x", color="C1", ms=4,
                    label="not one rotation",
                )  # fmt: skip
        ax.set_ylabel(f"{name}\n[deg/s]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", ncol=2)
    axes[-1].set_xlabel("time since start [s]")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return path


SNN_REAL_DATA_NOTE = (
    "note: on real cameras the SNN is not yet accurate (the shipped snn6: 31 deg/s mean error on "
    "a steady 5 deg/s pan, translBoxes; --checkpoint snn6-real, on the event clock: 3.4, below "
    "omega = 0's 5.0, but 17 deg/s on a real roll; see BENCHMARKS.md): use --method cmax for "
    "real recordings."
)
"""The line ``predict`` prints when the network runs on a recording that is not simulated."""


def is_simulated(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a sequence written by spikegyro's simulator (its ``generator``
    attribute says so); real camera files and text recordings are not."""
    path = Path(path)
    try:
        if detect_format(path) != "hdf5":
            return False
        return str(read_hdf5_attrs(path).get("generator", "")).startswith("spikegyro")
    except (OSError, InputError):
        return False


def summary_lines(result: StreamResult, out: str | os.PathLike, warm_up: bool = False) -> list[str]:
    """What ``predict`` prints at the end: output, speed, latency, ill-posed estimates, errors;
    with ``warm_up`` (the network), a warning when the run ends within its warm-up."""
    seconds = result.steps * BIN_US / 1e6
    lines = [
        f"{result.estimates:,} estimates ({result.rate_hz:.0f} per second, {seconds:.3f} s, "
        f"{result.events:,} events) -> {out}; {result.wall_s:.1f} s wall, "
        f"{result.realtime_factor:.1f}× real time ({result.cpu_realtime_factor:.1f}× per "
        "CPU-second)",
        f"engine: {result.engine}",
    ]
    if result.estimates == 0 and result.why_none:
        lines.append(f"warning: no estimate: {result.why_none}; the output holds only its header.")
    elif result.estimates == 0:
        lines.append(
            f"warning: no estimate: {result.events:,} events in {seconds:.3f} s are too few for "
            "one (a window needs a few thousand events); the output holds only its header."
        )
    elif warm_up and result.steps <= WARMUP_STEPS:
        lines.append(
            f"warning: {result.steps} ms of output is within the network's {WARMUP_STEPS} ms "
            "warm-up, where it reads about zero; predict over a longer span to get estimates."
        )
    if math.isfinite(result.latency_ms):
        lines.append(
            f"latency: each estimate is the mean rate over its window, whose events lie "
            f"{result.latency_ms:.1f} ms (median) before the estimate's time"
        )
    few, little, not_one = result.ill_posed
    if few or little:
        lines.append(
            f"warning: {few:,} of {result.estimates:,} estimates had fewer events than asked "
            f"for and {little:,} moved edges too little to tell from none (under a pixel, or "
            "a few pixels that sharpen nothing): see the ill_posed column; their ω is "
            "unreliable."
        )
    if not_one:
        lines.append(
            f"warning: one rotation does not explain the events of {not_one:,} of "
            f"{result.estimates:,} estimates (ill_posed bit 4: parts of the image disagree, the "
            "motion sharpens nothing, or the events are one object in a still view): the scene "
            "itself may move; their ω is unreliable."
        )
    if result.stats:
        s = result.stats
        lines.append(
            f"vs gyro (from {WARMUP_STEPS} ms on, {s['samples']:,} estimates): mean absolute "
            f"error tilt {s['mae_x_deg_s']:.2f}, pan {s['mae_y_deg_s']:.2f}, roll "
            f"{s['mae_z_deg_s']:.2f} deg/s; mean error {s['mean_error_deg_s']:.1f} deg/s, RMSE "
            f"{s['rmse_deg_s']:.1f} deg/s (x {s['rmse_x_deg_s']:.1f}, y {s['rmse_y_deg_s']:.1f}, "
            f"z {s['rmse_z_deg_s']:.1f}), median relative error {s['median_relative_error']:.3f}"
        )
    if result.plot is not None:
        lines.append(f"plot -> {result.plot}")
    return lines
