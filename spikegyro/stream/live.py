"""``predict`` on a live source: estimates written as the stream's events arrive.

:func:`predict_live` feeds each batch of a :class:`~spikegyro.events.sources.LiveSource` to a
:class:`~spikegyro.stream.estimator.GyroEstimator` the moment it arrives and writes the
estimates it completes at once (``--out -``: CSV lines on standard output, flushed per
batch). The output clock, ``--start`` and ``--end`` count from the first event's whole
millisecond, as for a file, so a recording served live at any pace gives the estimates the
file gives (the estimators do not depend on how events are batched).

Nothing is dropped. How far behind the stream the output falls is measured per batch: the
time from the batch's arrival, had it come as early as the fastest batch came relative to its
events' clock, to its estimates being written. It is reported when it passes
:data:`BEHIND_WARN_MS` (and again at each doubling) and summarized at the end.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from rich.console import Console

from spikegyro.errors import InputError, Interrupted, check_interrupt, is_interrupt
from spikegyro.events.blocks import ImuBlock
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.events.imu import rotate_to_camera
from spikegyro.events.sources import LiveSource, parse_url
from spikegyro.events.windows import BIN_US
from spikegyro.stream.console import print_lines
from spikegyro.stream.estimator import GyroEstimator
from spikegyro.stream.predict import (
    SNN_REAL_DATA_NOTE,
    StreamResult,
    _StreamRun,
    check_span,
    summary_lines,
)
from spikegyro.stream.writer import PredictionWriter

BEHIND_WARN_MS = 100.0
"""Output this far behind the stream (ms) is reported as it happens."""
_IMU_KEEP_US = 2_000_000
_LAG_BINS_MS = 600_000


class LagMeter:
    """How far the output runs behind the stream, per batch (1 ms histogram, bounded memory).

    The clock offset between the stream's timestamps and this machine's wall clock is taken
    as the smallest seen (arrival wall time − the batch's last event time): the batch that
    came soonest sets zero lag.
    """

    def __init__(self, notify: Callable[[str], None]) -> None:
        self.notify = notify
        self.offset_us = math.inf
        self.hist = np.zeros(_LAG_BINS_MS + 1, dtype=np.int64)
        self.max_ms = 0.0
        self._warned_ms = BEHIND_WARN_MS / 2

    def arrived(self, t_last_us: int) -> None:
        """A batch whose last event is at ``t_last_us`` arrived now."""
        self.offset_us = min(self.offset_us, time.time() * 1e6 - t_last_us)

    def written(self, t_last_us: int) -> float:
        """Its estimates are written now; returns the lag, ms."""
        lag_ms = max(0.0, (time.time() * 1e6 - self.offset_us - t_last_us) / 1000)
        self.hist[min(int(lag_ms), _LAG_BINS_MS)] += 1
        self.max_ms = max(self.max_ms, lag_ms)
        if lag_ms >= 2 * self._warned_ms:
            self._warned_ms = lag_ms
            self.notify(
                f"warning: {lag_ms:.0f} ms behind the stream (estimates come later than events "
                "arrive; none are dropped): use a faster method, a lower --rate-hz or a free core."
            )
        return lag_ms

    def percentile_ms(self, q: float) -> float:
        """The ``q``-th percentile of the lag, ms (upper edge of its 1 ms bin); NaN if none."""
        cum = np.cumsum(self.hist)
        if not cum[-1]:
            return float("nan")
        return float(np.searchsorted(cum, math.ceil(q / 100 * cum[-1])) + 1)


@dataclass
class LiveResult:
    """What :func:`predict_live` did: the run (:class:`StreamResult`), the lag (median, 95th
    percentile and maximum, ms), the bytes of a packet cut short at the end, and whether
    Ctrl-C ended it."""

    run: StreamResult
    lag_ms: tuple[float, float, float] = (float("nan"),) * 3
    truncated: int = 0
    interrupted: bool = False


class _ImuReference:
    """The stream's own gyro as the reference: its recent samples, rotated into the camera
    frame."""

    def __init__(self, rotation: np.ndarray | None) -> None:
        self.rotation = rotation
        self.t = np.zeros(0, np.int64)
        self.omega = np.zeros((0, 3))

    def add(self, block: ImuBlock) -> GyroTrace:
        keep = self.t > int(block.t[-1]) - _IMU_KEEP_US if len(block.t) else slice(None)
        self.t = np.concatenate([self.t[keep], block.t])
        self.omega = np.concatenate(
            [self.omega[keep], rotate_to_camera(block.omega, self.rotation)]
        )
        return GyroTrace(t=self.t, omega=self.omega)


class _LiveRun:
    """One live run: the clock set by the first event, the span, the writer and the lag."""

    def __init__(self, estimator: GyroEstimator, writer: PredictionWriter, lag: LagMeter,
                 start_s: float, end_s: float | None) -> None:  # fmt: skip
        self.estimator, self.writer, self.lag = estimator, writer, lag
        self.start_s, self.end_s = start_s, end_s
        self.run: _StreamRun | None = None
        self.gyro: GyroTrace | None = None
        self.t0 = self.t_end = self.last_t = None

    def events(self, batch: EventArray) -> bool:
        """Feed a batch; False once ``--end`` is reached."""
        if not len(batch):
            return True
        self.lag.arrived(int(batch.t[-1]))
        if self.run is None:
            t_first = int(batch.t[0]) // BIN_US * BIN_US
            self.t0 = t_first + round(self.start_s * 1e6)
            self.t_end = None if self.end_s is None else t_first + round(self.end_s * 1e6)
            self.estimator.reset(self.t0)
            self.run = _StreamRun(self.gyro, self.t0)
        lo = int(np.searchsorted(batch.t, self.t0))
        hi = len(batch) if self.t_end is None else int(np.searchsorted(batch.t, self.t_end))
        if hi > lo:
            chunk = batch[lo:hi]
            self.run.result.events += len(chunk)
            self.last_t = int(chunk.t[-1])
            self.run.emit(self.writer, self.estimator.update(chunk))
            self.lag.written(int(batch.t[-1]))
        return hi == len(batch)

    def imu(self, gyro: GyroTrace) -> None:
        self.gyro = gyro
        if self.run is not None:
            self.run.gyro = gyro

    def finish(self, source: str, interrupted: bool) -> StreamResult:
        """The estimates still due, to ``--end`` (or the last event, after Ctrl-C)."""
        if self.run is None or self.last_t is None:
            if interrupted:
                raise Interrupted()
            raise InputError(
                f"{source}: the stream ended with no events between --start and --end."
            )
        end = self.t_end if self.t_end is not None and not interrupted else self.last_t + 1
        self.run.emit(self.writer, self.estimator.finish(end))
        return self.run.finish(end, self.estimator.label)


def predict_live(
    source: LiveSource,
    estimator: GyroEstimator,
    out: str | os.PathLike,
    *,
    start_s: float = 0.0,
    end_s: float | None = None,
    gyro_rotation: np.ndarray | None = None,
    notify: Callable[[str], None] = print,
) -> LiveResult:
    """Run ``estimator`` on ``source`` until the stream ends, ``end_s`` (s after its first
    event) is reached or Ctrl-C; estimates go to ``out`` (``.csv``/``.h5``, or ``-`` for CSV on
    standard output) as they complete. Where the source has an IMU, its gyro (rotated by
    ``gyro_rotation``, R with ω_camera = R · ω_imu) is the reference of each estimate.
    ``notify`` gets the lines to tell the user while it runs."""
    check_span(start_s, end_s)
    confidence = bool(getattr(estimator, "confidence", False))
    steps = bool(getattr(estimator, "clocked", False))
    imu = _ImuReference(gyro_rotation) if source.has_imu else None
    interrupted = False
    lag = LagMeter(notify)
    with PredictionWriter(
        out, with_gyro=imu is not None, with_confidence=confidence, with_steps=steps
    ) as writer:
        live = _LiveRun(estimator, writer, lag, start_s, end_s)
        try:
            for item in source.batches():
                check_interrupt()
                if isinstance(item, ImuBlock):
                    live.imu(imu.add(item))
                elif not live.events(item):
                    break
        except BaseException as exc:  # Ctrl-C: what was read is still estimated and written
            if not is_interrupt(exc):
                raise
            interrupted = True
        finally:
            source.close()
        result = live.finish(source.name, interrupted)
    lags = (lag.percentile_ms(50), lag.percentile_ms(95), lag.max_ms)
    return LiveResult(result, lags, source.truncated, interrupted)


def check_live_options(
    source: str, gyro: object | None, width: int | None, height: int | None
) -> None:
    """The options that a live source refuses (before connecting): the URL is checked, the
    sensor size and a gyro file come from the stream."""
    parse_url(source)
    if gyro is not None:
        raise InputError(
            f"--gyro with {source}: a gyro file's clock is not the stream's; the stream's own "
            "IMU, where it has one, is the reference."
        )
    if width is not None or height is not None:
        raise InputError(f"--width/--height with {source}: the stream gives its sensor size.")


def run_live(
    console: Console,
    source: LiveSource,
    estimator: GyroEstimator,
    out: str | os.PathLike,
    start_s: float,
    end_s: float | None,
    gyro_rotation: np.ndarray | None,
    method: str,
) -> None:
    """``predict`` on a live source: :func:`predict_live`, then its summary; Ctrl-C ends it
    with every completed estimate written and then :class:`Interrupted` (exit 130)."""
    console.print(
        f"reading {source.name}: {source.sensor[0]}x{source.sensor[1]} px"
        + (", with its IMU as the reference" if source.has_imu else "")
        + "; Ctrl-C stops"
    )
    live = predict_live(source, estimator, out, start_s=start_s, end_s=end_s,
                        gyro_rotation=gyro_rotation, notify=console.print)  # fmt: skip
    print_lines(console, summary_lines(live.run, out, warm_up=method == "snn"))
    print_lines(console, live_summary_lines(live, source.name))
    if method == "snn":
        console.print(SNN_REAL_DATA_NOTE)
    if live.interrupted:
        raise Interrupted()


def live_summary_lines(live: LiveResult, source: str) -> list[str]:
    """What ``predict`` adds on a live source: how the stream ended and how far behind the
    output ran."""
    how = "Ctrl-C" if live.interrupted else "the stream's end"
    lines = [f"stopped at {how}; every estimate completed by then is written"]
    if live.truncated:
        lines.append(
            f"warning: {source} ended {live.truncated} bytes into a packet; its events are lost."
        )
    median, p95, most = live.lag_ms
    if math.isfinite(median):
        lines.append(
            f"behind the stream: median {median:.0f} ms, 95th percentile {p95:.0f} ms, at most "
            f"{most:.0f} ms (per batch, from its arrival to its estimates written; no events "
            "dropped)"
        )
    return lines
