"""Contrast maximization over a whole recording: each estimate from the events around its time.

Where the live engine (:mod:`spikegyro.cmax.live`) may use only the past and must keep up, a
file can be post-processed: the estimate for time ``t`` uses the events of a window centred on
``t``, so it stands for ``t`` itself (the mean rate over a centred window lags a steady change
of ω by nothing, to first order), with more events and more iterations than live tracking
affords. Per output time (``t0 + k / rate_hz`` within the recording, or its middle when the
recording is shorter than one period):

1. the window: at least ``min_events`` events and long enough that the neighbouring estimate
   moves edges by ``target_px`` pixels across it, within ``min_ms`` and ``max_ms``;
2. its events (hot pixels dropped, thinned evenly to ``max_events``) as rays, warped to ``t``;
3. BFGS to convergence at the two finest pyramid levels from the previous estimate, and the
   global search (:func:`spikegyro.cmax.search.search`) at the first estimate, every
   ``search_every_s`` and wherever the contrast gain collapses;
4. on a recording that spans at most ``whole_max_ms``, one estimate from all its events (that of
   ``spikegyro baseline cmax --whole``) starts the first search, and each estimate keeps its
   window's own ω or takes the whole span's, whichever sharpens the events around it more
   (below);
5. the same confidence as live estimates (``ill_posed`` bits 1, 2 and 4).

Local or whole (step 4). A short window's ω is noisy: a tenth of a pixel of blur over a window
that moves edges by 8 px is 1 % of the rate. Where the rotation holds over the recording, the
whole span's ω, from all its events over many more pixels of motion, is better; where it
changes, the window's own is. Two that move edges less than ``resolve_px`` apart over the
whole recording cannot be told apart by its events, and the whole span's is taken. Otherwise
they are compared on the events around the window, over a centred window twice as long (or
long enough that they move its edges ``resolve_px`` apart; symmetric about the estimate's time
as far as the recording allows, where a rate that changes linearly averages to the rate at its
centre), its own events left out (the window's ω was fitted to them, noise included, and
always sharpens them best), and the one that sharpens them more is the estimate. A window that
spans almost the whole recording takes the whole span's ω: both are maxima of the contrast of
the same events.

:func:`estimate_offline` is the function over events in memory; :class:`OfflineCMax` wraps it
in the estimator interface so that ``spikegyro predict --method cmax --offline`` writes, scores
and plots it like the live engine (it answers everything at ``finish``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from spikegyro.cmax.confidence import rotation_flags
from spikegyro.cmax.config import CMaxConfig, Progress
from spikegyro.cmax.files import camera_for_file
from spikegyro.cmax.problem import (
    Intrinsics,
    Problem,
    base_scale,
    default_camera,
    dither,
    event_rays,
)
from spikegyro.cmax.search import Refined, estimate_whole, search
from spikegyro.cmax.series import per_ms
from spikegyro.cmax.windows import pixel_speed, rms_radius
from spikegyro.events.calib import Calibration
from spikegyro.events.core import EventArray
from spikegyro.events.windows import BIN_US, series_per_window
from spikegyro.stream.estimator import (
    ILL_FEW_EVENTS,
    ILL_LITTLE_MOTION,
    Estimates,
)


@dataclass(frozen=True)
class OfflineConfig:
    """Settings of the offline engine (see the module).

    Attributes:
        rate_hz: estimates per second of event time.
        min_events: a window holds at least this many events (where the recording has them).
        target_px: ... and is long enough that ω moves edges this far across it, px.
        min_ms, max_ms: bounds of the window's length, ms.
        search_every_s: the global search runs at the first estimate and then every this many
            seconds of event time (and wherever the gain falls below half its recent best).
        whole_max_ms: a recording spanning at most this many ms also gets one estimate from
            all its events, and each estimate takes it where it sharpens the events around the
            estimate more than the window's own (see the module); 0: never.
        resolve_px: that comparison's window is at least long enough that the two move its
            edges this far apart, binned px.
        base: the one-window settings (blur, pyramid, grid, iterations, events, one-rotation
            test); ``max_events`` and ``iterations`` default higher than live tracking's.
    """

    rate_hz: float = 100.0
    min_events: int = 10_000
    target_px: float = 8.0
    min_ms: float = 4.0
    max_ms: float = 200.0
    search_every_s: float = 0.1
    whole_max_ms: float = 200.0
    resolve_px: float = 1.0
    base: CMaxConfig = field(default_factory=lambda: CMaxConfig(max_events=30_000, iterations=30))


def offline_times(t_first_us: int, t_last_us: int, t0_us: int, rate_hz: float) -> np.ndarray:
    """Output times (µs, int64) ``t0 + k / rate`` (k >= 1) within ``[t_first, t_last]``; the
    middle of the span when none falls there."""
    period = 1e6 / rate_hz
    k = np.arange(1, int((t_last_us - t0_us) / period) + 2)
    t = np.rint(t0_us + k * period).astype(np.int64)
    t = t[(t >= t_first_us) & (t <= t_last_us)]
    return t if len(t) else np.array([(t_first_us + t_last_us) // 2], np.int64)


@dataclass
class _Rays:
    """All usable events of a recording as rays (dithered within their pixel), with times."""

    t: np.ndarray
    bx: np.ndarray
    by: np.ndarray


def _rays(events: EventArray, camera: Intrinsics, config: CMaxConfig) -> _Rays:
    """Rays of ``events``, hot pixels (over the whole recording) and undefined rays dropped;
    dithered as in the live engine, so that ω = 0 gets no spurious peak."""
    keep, bx, by = event_rays(events, camera, config.hot_pixel_factor)
    rng = np.random.default_rng(config.seed + 1)
    bx, by = dither(bx[keep], by[keep], camera.fx, camera.fy, rng)
    return _Rays(events.t[keep].astype(np.int64), bx, by)


def _window(rays: _Rays, t_us: int, speed: float | None, config: OfflineConfig) -> np.ndarray:
    """Indices of the (evenly thinned) events of the window centred on ``t_us``."""
    t, n = rays.t, len(rays.t)
    mid = int(np.searchsorted(t, t_us))
    half = config.min_events // 2
    lo, hi = max(mid - half, 0), min(mid + half, n - 1)
    by_count = max(t_us - t[lo], t[hi] - t_us) if n else 0.0
    by_motion = 0.5e6 * config.target_px / speed if speed else 0.0
    half_us = min(max(by_count, by_motion, 500.0 * config.min_ms), 500.0 * config.max_ms)
    a = int(np.searchsorted(t, t_us - half_us, side="left"))
    b = int(np.searchsorted(t, t_us + half_us, side="right"))
    return _thinned(np.arange(a, b), config.base.max_events)


def _thinned(index: np.ndarray, most: int) -> np.ndarray:
    """``index`` thinned evenly to at most ``most`` entries."""
    if len(index) <= most:
        return index
    return index[np.linspace(0, len(index) - 1, most).astype(np.intp)]


class _Engine:
    """The state of one pass: the previous estimate, its search time, recent gains and the
    whole span's ω (None: not used)."""

    def __init__(
        self, rays: _Rays, camera: Intrinsics, sensor: tuple[int, int], cfg: OfflineConfig
    ) -> None:
        self.rays, self.config, self.sensor = rays, cfg, sensor
        self.intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy])
        self.radius = rms_radius(*sensor, camera.cx, camera.cy)
        self.base = base_scale(*sensor, cfg.base.max_pixels)
        self.omega: np.ndarray | None = None
        self.searched_us: int | None = None
        self.best_gain = 0.0
        self.rng = np.random.default_rng(cfg.base.seed)
        self.whole: np.ndarray | None = None

    def _problem(self, index: np.ndarray, t_us: int) -> Problem:
        """The events ``index`` of the rays, warped to ``t_us``."""
        rays = self.rays
        dt = (t_us - rays.t[index]) * 1e-6
        return Problem(
            rays.bx[index], rays.by[index], dt, np.ones(len(index)), self.intrinsics,
            *self.sensor, self.base,
        )  # fmt: skip

    def speed(self, omega: np.ndarray | None) -> float | None:
        """Image speed (px/s of the objective's binned image) under ω (rad/s; None: none)."""
        if omega is None:
            return None
        return pixel_speed(omega, float(self.intrinsics[0]), self.radius) / self.base

    def estimate(self, t_us: int) -> tuple | None:
        """One estimate at ``t_us`` (a row of ``Estimates``), or None without events."""
        index = _window(self.rays, t_us, self.speed(self.omega), self.config)
        base = self.config.base
        if len(index) < max(base.min_events, 2):
            return None
        problem = self._problem(index, t_us)
        found = self._maximize(problem, t_us)
        omega, sharp = found.omega, found.contrast
        if self.whole is not None and self._whole_sharper(t_us, omega, index):
            omega = self.whole
            sharp = problem.contrast(omega, 1, base.sigma_px)[0]
        flat = problem.contrast(np.zeros(3), 1, base.sigma_px)[0]
        gain = sharp / flat if flat > 0 else math.nan
        if math.isfinite(gain):
            self.best_gain = max(gain - 1.0, self.best_gain * 0.9)
        t = self.rays.t[index]
        span = float(t[-1] - t[0])
        return (
            t_us,
            omega,
            len(index),
            span,
            float(problem.dt.mean()) * 1e6,
            gain,
            self._flags(problem, omega, span),
        )

    def _whole_sharper(self, t_us: int, omega: np.ndarray, index: np.ndarray) -> bool:
        """Whether the whole span's ω sharpens the events around the window (its events
        ``index``) at least as much as the window's own ``omega`` (rad/s) (see the module)."""
        rays, base = self.rays, self.config.base
        first, last = int(index[0]), int(index[-1])
        if rays.t[last] - rays.t[first] >= 0.9 * (rays.t[-1] - rays.t[0]):
            # The window is (almost) the whole span: two maxima of the same events' contrast
            # differ by chance, and the whole span's uses all its events.
            return True
        local_us = float(max(t_us - rays.t[first], rays.t[last] - t_us))
        apart = self.speed(self.whole - omega)
        if apart * float(rays.t[-1] - rays.t[0]) * 1e-6 < self.config.resolve_px:
            # Even the whole span's events cannot tell the two apart: the one from more events.
            return True
        half_us = max(0.5e6 * self.config.resolve_px / apart if apart else 0.0, 2.0 * local_us)
        # Symmetric about t where the recording allows: a window's mean rate is ω at its centre
        # (to first order), and a one-sided one would favour the whole span's over a change.
        edge_us = float(min(t_us - rays.t[0], rays.t[-1] - t_us))
        half_us = max(min(half_us, edge_us), local_us)
        a = int(np.searchsorted(rays.t, t_us - half_us, side="left"))
        b = int(np.searchsorted(rays.t, t_us + half_us, side="right"))
        # Judged on the events around the window, not on its own: the window's ω was fitted to
        # its own events, noise included, so on them it always looks sharper.
        flanks = np.r_[np.arange(a, first), np.arange(last + 1, b)]
        if len(flanks) < max(base.min_events, 2):
            flanks = np.arange(a, b)
        check = self._problem(_thinned(flanks, base.max_events), t_us)
        whole = check.contrast(self.whole, 1, base.sigma_px)[0]
        return whole >= check.contrast(omega, 1, base.sigma_px)[0]

    def _maximize(self, problem: Problem, t_us: int) -> Refined:
        """Search where due, else refine from the previous estimate to convergence."""
        base, every = self.config.base, self.config.search_every_s * 1e6
        due = self.omega is None or self.searched_us is None or t_us - self.searched_us >= every
        if not due:
            tracked = search(problem, base, self.omega, grid=False, rng=self.rng)
            flat = problem.contrast(np.zeros(3), 1, base.sigma_px)[0]
            share = (tracked.contrast / flat - 1.0) / self.best_gain if self.best_gain else 1.0
            if share >= 0.5:
                self.omega = tracked.omega
                return tracked
        # The first search also starts from the whole span's ω: a short window's own events may
        # hold too little to find the maximum from the grid.
        init = self.omega if self.omega is not None or self.whole is None else self.whole
        found = search(problem, base, init, grid=True, rng=self.rng)
        self.searched_us, self.omega = t_us, found.omega
        return found

    def _flags(self, problem: Problem, omega: np.ndarray, span_us: float) -> int:
        """``ill_posed`` bits 1, 2 and 4 of estimate ω of ``problem``."""
        config, flags = self.config, 0
        if len(problem) < config.min_events and len(problem) < config.base.max_events:
            flags |= ILL_FEW_EVENTS
        moved = self.speed(omega) * span_us * 1e-6
        if moved < config.base.min_motion_px:
            flags |= ILL_LITTLE_MOTION
        return flags | rotation_flags(problem, omega, moved, config.base, self.rng)


def estimate_offline(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: OfflineConfig | None = None,
    t0_us: int | None = None,
    progress: Progress | None = None,
    since_us: int | None = None,
) -> Estimates:
    """Offline estimates over a recording in memory, one per ``1 / config.rate_hz`` s.

    Args:
        events: the recording's events, on the sensor's pixels, time-ordered.
        camera: the sensor's intrinsics or ``Calibration``; default the simulator's pinhole.
        config: settings (:class:`OfflineConfig`).
        t0_us: the output clock's origin (default: the first event's whole millisecond).
        progress: optional ``progress(done, total)`` after each estimate.
        since_us: no estimates before the last output time at or before this, µs (None: all).

    Returns:
        ``Estimates`` stamped at the times they stand for (the windows' centres; ``delay_us``
        is how far the events' mean time lies before it, about 0).
    """
    config = config or OfflineConfig()
    if len(events) < 2:
        return Estimates.empty()
    camera = camera or default_camera(events.width, events.height)
    t0 = int(events.t[0]) // BIN_US * BIN_US if t0_us is None else int(t0_us)
    times = offline_times(int(events.t[0]), int(events.t[-1]), t0, config.rate_hz)
    if since_us is not None:
        times = times[max(int(np.searchsorted(times, since_us, side="right")) - 1, 0) :]
    engine = _Engine(_rays(events, camera, config.base), camera, events.sensor_size, config)
    if events.duration_us <= 1e3 * config.whole_max_ms:
        engine.whole = estimate_whole(events, camera)
    rows = []
    for k, t_us in enumerate(times.tolist()):
        row = engine.estimate(t_us)
        if row is not None:
            rows.append(row)
        if progress is not None:
            progress(k + 1, len(times))
    if not rows:
        return Estimates.empty()
    return Estimates(*(np.array(c) for c in zip(*rows, strict=True)))


class OfflineCMax:
    """:func:`estimate_offline` behind the estimator interface (``update`` keeps the events,
    ``finish`` answers every estimate), for ``predict --method cmax --offline``."""

    confidence = True

    def __init__(self, camera: Intrinsics | None = None, config: OfflineConfig | None = None):
        self.camera, self.config = camera, config or OfflineConfig()
        self.label = f"contrast maximization, offline (centred windows), {self.config.rate_hz:g} Hz"
        self.reset()

    def reset(self, t0_us: int | None = None) -> None:
        """Forget the events; the output clock starts at ``t0_us``."""
        self.t0_us, self._parts, self._found = t0_us, [], 0

    def update(self, events: EventArray) -> Estimates:
        """Keep a batch; offline estimates come at :meth:`finish`."""
        if len(events):
            self._parts.append(events)
        return Estimates.empty()

    def finish(self, t_end_us: int) -> Estimates:
        """All estimates over the events kept, up to ``t_end_us``."""
        if not self._parts:
            return Estimates.empty()
        events = EventArray.concatenate(self._parts)
        events = events.slice_time(int(events.t[0]), int(t_end_us) + 1)
        found = estimate_offline(events, self.camera, self.config, self.t0_us)
        self._found, self._seen = len(found), len(events)
        return found

    def why_none(self) -> str:
        """Why there was no estimate (empty when there was one)."""
        if self._found or not self._parts:
            return ""
        need = max(self.config.base.min_events, 2)
        return f"no window holds the {need:,} events (hot pixels dropped) an estimate needs"


SIMULATED_OFFLINE = OfflineConfig(rate_hz=200.0)
"""Offline estimates every 5 ms: the setting of ``spikegyro evaluate --model cmax``."""


def predict_windows_offline(
    windows: Sequence[Any],
    config: OfflineConfig | None = None,
    camera: Intrinsics | None = None,
    progress: Progress | None = None,
    first_step: int = 0,
) -> np.ndarray:
    """Per-ms ω (n, T, 3) rad/s for ``spikegyro.train.data.Window`` objects, offline.

    Each window is processed on its own (no events from outside it, as for the networks): its
    offline estimates every ``1 / config.rate_hz`` s (default :data:`SIMULATED_OFFLINE`),
    interpolated linearly to each 1 ms step's end (:func:`~spikegyro.cmax.series.per_ms`), the
    time the ground truth is sampled at. Steps before ``first_step`` are zero and cost nothing.
    """
    config = config or SIMULATED_OFFLINE

    def series(batch: Sequence[Any]) -> np.ndarray:
        (window,) = batch
        steps = int(np.asarray(window.omega).shape[0])
        t0 = int(window.t_start_us)
        ends = t0 + BIN_US * (np.arange(steps, dtype=np.int64) + 1)
        events = window.events.slice_time(t0, int(ends[-1]) + 1)
        est = estimate_offline(events, camera, config, t0, since_us=int(ends[first_step]) - 1)
        out = per_ms(est.t_us, est.omega, ends)
        out[:first_step] = 0.0
        return out[None]

    num_steps = int(np.asarray(windows[0].omega).shape[0]) if len(windows) else 0
    done = None if progress is None else lambda n: progress(n, len(windows))
    return series_per_window(series, windows, num_steps, progress=done)


def with_rate(config: OfflineConfig | None, rate_hz: float | None) -> OfflineConfig:
    """``config`` (None: the default) at ``rate_hz`` estimates per second (None: its own)."""
    config = config or OfflineConfig()
    return config if rate_hz is None else replace(config, rate_hz=float(rate_hz))


def offline_estimator_for_file(
    path: str | os.PathLike,
    calibration: Calibration | None = None,
    sensor: tuple[int, int] | None = None,
    rate_hz: float | None = None,
) -> tuple[OfflineCMax, str]:
    """An :class:`OfflineCMax` for an event file (intrinsics by
    :func:`~spikegyro.cmax.files.camera_for_file`) and the line saying which intrinsics."""
    camera, note = camera_for_file(path, calibration, sensor)
    return OfflineCMax(camera, with_rate(None, rate_hz)), note
