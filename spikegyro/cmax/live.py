"""Contrast maximization as a live gyroscope: causal, adaptive windows at a fixed output rate.

:class:`CMaxEstimator` implements :class:`spikegyro.stream.estimator.GyroEstimator`: fed event
batches as they arrive, it answers ω at ``t0 + k / rate_hz`` (or once per batch), each estimate
from the events in ``(t - W, t]`` only. Per estimate:

1. the window ``W`` (:class:`~spikegyro.cmax.windows.WindowPolicy`): enough events
   and enough image motion under the previous estimate, within bounds;
2. its events (hot pixels dropped, evenly thinned to ``track_events``) as rays, warped to ``t``;
3. a few BFGS steps at full resolution from the previous estimate with the exact-gradient
   Numba objective (:mod:`spikegyro.cmax.iwe`); instead, at the first estimate and when the
   contrast gain collapses (the motion changed abruptly), ω = 0 and the previous estimate
   refined coarse to fine, and a global search (:func:`spikegyro.cmax.search.search`);
4. its confidence: events used, window, the contrast over that of ω = 0, and flags when
   ill-posed (too few events, too little motion, not one rotation).

The global searches (those, and one every ``search_every_s``, sooner when tracking is in doubt)
and the one-rotation test cost tens of estimates' work each. Run in line they would hold up the
estimates behind them by hundreds of milliseconds, so they run on threads of their own (the
Numba code releases the GIL) on a copy of their window, and their results are taken up at a
fixed later point of event time: a search's at the first estimate ``search_lag_ms`` after it
started (its ω refined on that estimate's window, competing with the tracked one), a test's
verdict at the next estimate (the stream's first verdict at once). The main thread waits
there if the job is not done, so the estimates do not depend on threads, timing or batching,
and a file gives the same estimates as a live stream of it. Searches and tests have a thread
each, so that a verdict never queues behind a search, and the searches' thread runs at the
lowest scheduling priority (where the OS allows it): on a single core it then takes only the
time that the estimates leave, instead of holding them up while it runs.

Memory is bounded: only the events of the longest window are kept, as rays, in a buffer that
grows to the largest window seen and is reused.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from spikegyro.cmax.confidence import rotation_flags
from spikegyro.cmax.config import CMaxConfig, Progress
from spikegyro.cmax.problem import (
    Intrinsics,
    Problem,
    base_scale,
    camera_rays,
    default_camera,
    dither,
)
from spikegyro.cmax.search import Refined, refine, search
from spikegyro.cmax.windows import (
    EventBuffer,
    HotPixels,
    Thinning,
    event_rate,
    pixel_speed,
    predicted_speed,
    rms_radius,
)
from spikegyro.events.core import EventArray
from spikegyro.events.windows import BIN_US
from spikegyro.stream.estimator import (
    ILL_FEW_EVENTS,
    ILL_LITTLE_MOTION,
    Estimates,
    output_times,
)

_NEVER = -(1 << 62)
_SEARCH, _TEST = 0, 1  # the kinds of background job (each has its thread and RNG streams)


def _lowest_priority() -> None:
    """Give the calling thread the lowest scheduling priority, where the OS has per-thread
    priorities (Linux); elsewhere it keeps the process's."""
    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)


class CMaxEstimator:
    """Causal contrast-maximization gyroscope (see the module); a ``GyroEstimator``.

    Args:
        camera: the sensor's intrinsics (``PinholeCamera``) or ``Calibration`` (then events are
            undistorted); default :func:`~spikegyro.cmax.problem.default_camera` of the
            first batch's sensor.
        config: settings (:class:`~spikegyro.cmax.config.CMaxConfig`; 100 Hz, adaptive).
        t0_us: origin of the output clock, µs (default: the first event's whole millisecond).
    """

    def __init__(
        self,
        camera: Intrinsics | None = None,
        config: CMaxConfig | None = None,
        t0_us: int | None = None,
    ) -> None:
        self.camera = camera
        self.config = config or CMaxConfig()
        rate = f"{self.config.rate_hz:g} Hz" if self.config.rate_hz > 0 else "one per batch"
        self.label = (
            f"contrast maximization, causal windows, {rate} (CPU, 1 thread + 2 for searches "
            "and tests)"
        )
        self.confidence = True
        self._workers: dict[int, ThreadPoolExecutor] = {}
        self.reset(t0_us)

    def reset(self, t0_us: int | None = None) -> None:
        """Forget the stream; the next batch starts a new one with its clock at ``t0_us``."""
        self.t0_us = t0_us
        self.emitted = 0
        self.produced = 0
        self._seen = self._in_view = 0
        self._verdict, self._tested_us, self._quiet_us = 0, _NEVER, _NEVER
        self.searches = 0
        self._search_job: tuple[Future, int] | None = None
        self._test_job: Future | None = None
        self._omega: np.ndarray | None = None
        self._last_search_us: int | None = None
        self._hessian: np.ndarray | None = None
        self._alpha = np.zeros(3)
        self._bend_hessian: np.ndarray | None = None
        self._doubt = 1.0
        self._best_gain = 0.0
        self._collapse_us: int | None = None  # the last search after a collapse of the gain
        self._last_t: int | None = None
        self._window_rate = 0.0  # events/s of the previous estimate's window
        self._window_span_us = 0.0  # and its span, µs
        self._buffer = EventBuffer()
        self._thinning = Thinning(self.config.ingest_rate)
        self._hot: HotPixels | None = None
        self._rays: tuple[np.ndarray, np.ndarray] | None = None
        self._sensor: tuple[int, int] | None = None
        self._rng = np.random.default_rng(self.config.seed)
        self._dither = np.random.default_rng(self.config.seed + 1)
        self._counted_us: int | None = None

    def update(self, events: EventArray) -> Estimates:
        """Add a time-ordered batch; returns the estimates it completes.

        A fixed-rate estimate at ``t`` is due once an event later than ``t`` has arrived (later
        events cannot change it); at ``rate_hz = 0`` the batch gets one estimate at its last
        event.
        """
        if not len(events):
            return Estimates.empty()
        self._append(events)
        t_last = int(events.t[-1])
        if self.config.rate_hz <= 0:
            due = np.array([t_last], np.int64)
        else:
            due = output_times(self.t0_us, self.config.rate_hz, self.emitted, t_last - 1)
        return self._estimate_all(due)

    def finish(self, t_end_us: int) -> Estimates:
        """The fixed-rate estimates still due up to ``t_end_us`` (inclusive), µs."""
        if self.t0_us is None or self.config.rate_hz <= 0:
            return Estimates.empty()
        due = output_times(self.t0_us, self.config.rate_hz, self.emitted, int(t_end_us))
        found = self._estimate_all(due)
        if self.produced or self._last_t is None:
            return found
        # A stream shorter than the output period (or whose windows never filled) still gets
        # one estimate from all its events, stamped at the last of them.
        return self._estimate_all(np.array([self._last_t], np.int64), count=False, wait=False)

    def run(
        self,
        events: EventArray,
        t_end_us: int | None = None,
        progress: Progress | None = None,
        batch_us: int = 100_000,
    ) -> Estimates:
        """All estimates over events in memory, fed in batches of ``batch_us`` of event time."""
        if not len(events):
            return Estimates.empty()
        end = int(events.t[-1]) if t_end_us is None else int(t_end_us)
        events = events.slice_time(int(events.t[0]), end + 1)
        edges = np.arange(int(events.t[0]), end + batch_us + 1, batch_us)
        cuts = np.searchsorted(events.t, edges, side="left")
        parts = []
        for k in range(len(cuts) - 1):
            parts.append(self.update(events[int(cuts[k]) : int(cuts[k + 1])]))
            if progress is not None:
                progress(k + 1, len(cuts) - 1)
        parts.append(self.finish(end))
        return Estimates.concatenate(parts)

    def why_none(self) -> str:
        """Why the stream so far gave no estimate (empty when it gave one)."""
        if self.produced:
            return ""
        need = max(self.config.min_events, 2)
        hot = int(self._hot.hot.sum()) if self._hot is not None else 0
        if self._in_view == self._seen and not hot:
            return f"{self._seen:,} events are fewer than the {need:,} that an estimate needs"
        return (
            f"of {self._seen:,} events, {self._in_view:,} fall inside the calibrated field of "
            f"view and fewer than the {need:,} that an estimate needs remain once the events "
            f"of hot pixels ({hot:,} found) are dropped"
        )

    def _append(self, events: EventArray) -> None:
        """Rays of the batch into the buffer; hot-pixel counts updated."""
        if self._rays is None:
            self._start(events)
        if self._last_t is not None and events.t[0] < self._last_t:
            raise ValueError("events must arrive in time order")
        self._last_t = int(events.t[-1])
        x, y, t = events.x, events.y, events.t
        kept = self._thinning.keep(t)
        if kept is not None:
            x, y, t = x[kept], y[kept], t[kept]
        xs, ys = self._rays
        pix = y.astype(np.int32) * events.width + x.astype(np.int32)
        bx, by = xs.ravel()[pix], ys.ravel()[pix]
        ok = np.isfinite(bx) & np.isfinite(by)
        self._seen += len(ok)
        self._in_view += int(ok.sum())
        if not ok.all():
            pix, bx, by, t = pix[ok], bx[ok], by[ok], t[ok]
        # Dithered once, so that every estimate sees the same rays.
        fx, fy = self._intrinsics[:2]
        bx, by = dither(bx, by, fx, fy, self._dither)  # row by row: batching-independent
        self._buffer.append(t, bx, by, pix)

    def _start(self, events: EventArray) -> None:
        """Set up for the sensor of the first batch."""
        width, height = events.width, events.height
        self._sensor = (width, height)
        if self.camera is None:
            self.camera = default_camera(width, height)
        cam = self.camera
        self._rays = camera_rays(cam, width, height)
        self._intrinsics = np.array([cam.fx, cam.fy, cam.cx, cam.cy], dtype=np.float64)
        self._radius = rms_radius(width, height, cam.cx, cam.cy)
        self._base = base_scale(width, height, self.config.max_pixels)
        self._hot = HotPixels(width * height, self.config.hot_pixel_factor)
        if self.t0_us is None:
            self.t0_us = int(events.t[0]) // BIN_US * BIN_US

    def _estimate_all(self, due: np.ndarray, count: bool = True, wait: bool = True) -> Estimates:
        """The estimates at times ``due`` (µs); ``count``: they are on the output clock;
        ``wait``: the first estimate waits for a well-posed window."""
        rows = [row for row in (self._estimate(int(t), wait) for t in due) if row is not None]
        self.emitted += len(due) if count else 0
        self.produced += len(rows)
        if len(due):
            self._buffer.forget_before(int(due[-1]) - self.config.window.horizon_us)
        if not rows:
            return Estimates.empty()
        columns = list(zip(*rows, strict=True))
        return Estimates(*(np.array(c) for c in columns))

    def _count_hot(self, t_us: int) -> None:
        """Count the events up to ``t_us`` not counted yet into the hot-pixel detector (at
        estimate times only, so that the mask does not depend on how events were batched)."""
        t = self._buffer.times()
        lo = 0 if self._counted_us is None else int(np.searchsorted(t, self._counted_us, "right"))
        hi = int(np.searchsorted(t, t_us, side="right"))
        start = self._buffer.start
        self._hot.add(self._buffer.pix[start + lo : start + hi], t_us)
        self._counted_us = t_us

    def _search_due(self, t_us: int) -> bool:
        """Whether the estimate at ``t_us`` runs the global search: the first, then every
        ``search_every_s``, sooner while tracking is in doubt, and after a collapse of the
        contrast gain at once unless one ran within ``collapse_gap_ms``."""
        every = self.config.search_every_s * 1e6
        since = math.inf if self._last_search_us is None else t_us - self._last_search_us
        if self._omega is None:
            return True
        if self._doubt == 0.0:
            gap = t_us - self._collapse_us if self._collapse_us is not None else math.inf
            return gap >= 1000 * self.config.collapse_gap_ms
        return self._search_job is None and every > 0 and since >= every * self._doubt

    def _window(self, t_us: int, searching: bool) -> tuple[np.ndarray, float, int] | None:
        """Buffer indices of the (thinned) events of the window ending at ``t_us``, its span
        (µs) and its number of events (hot pixels included: the window is sized on them);
        None when fewer than ``min_events`` remain once hot pixels are left out."""
        self._count_hot(t_us)
        buf, config = self._buffer, self.config
        t = buf.times()
        i1 = int(np.searchsorted(t, t_us, side="right"))
        speed, policy = None, config.window
        if self._omega is not None:  # in the objective's (binned) pixels
            speed = self._speed(self._omega)
            long = self._window_span_us >= 1000 * policy.rate_min_ms
            if policy.rate_events > 0 and long:
                # The recent rate over a share of the previous window's span (a few hundred
                # events of a real sensor come in bursts), and over enough events.
                recent = math.floor(t_us - policy.rate_share * self._window_span_us)
                lo = min(int(np.searchsorted(t, recent, side="right")), i1 - policy.rate_events)
                rate = event_rate(t, max(lo, 0), i1)
                speed = predicted_speed(speed, rate, self._window_rate, policy.rate_rise)
        i0 = policy.start(t, i1, t_us, speed, searching)
        index = self._kept(i0, i1)
        if index is None:
            return None
        self._window_rate = event_rate(t, i0, i1)
        self._window_span_us = float(t_us - t[i0]) if i1 > i0 else 0.0
        span = float(t_us - buf.t[index[0]])
        return index, span, i1 - i0

    def _kept(self, i0: int, i1: int) -> np.ndarray | None:
        """Buffer indices of the events ``i0:i1`` of the buffer's times, hot pixels left out,
        evenly thinned to ``track_events``; None when fewer than ``min_events`` remain."""
        buf, config = self._buffer, self.config
        # A stride first where the window holds many times the budget (high event rates):
        # the hot-pixel lookup then costs O(budget), not O(window).
        stride = max(1, (i1 - i0) // (2 * config.track_events))
        index = np.arange(buf.start + i0, buf.start + i1, stride)
        index = index[~self._hot.is_hot(buf.pix[index])]
        if len(index) < max(config.min_events, 2):
            return None
        if len(index) > config.track_events:
            # Evenly thinned: the same share of every part of the window, at no random cost.
            index = index[np.linspace(0, len(index) - 1, config.track_events).astype(np.intp)]
        return index

    def _flags(
        self, problem: Problem, omega: np.ndarray, count: int, span_us: float, t_us: int
    ) -> int:
        """The ``ill_posed`` bits of estimate ω of ``problem``: too few events (``count``,
        hot pixels included), too little motion over ``span_us``, not one rotation."""
        config, flags = self.config, 0
        if count < config.window.posed_events and config.window.fixed_events <= 0:
            flags |= ILL_FEW_EVENTS
            self._note_quiet(t_us)
        moved = self._speed(omega) * span_us * 1e-6
        if moved < config.min_motion_px:
            flags |= ILL_LITTLE_MOTION
        if self._test_job is not None:
            self._verdict, self._test_job = self._test_job.result(), None
        test = config.one_rotation
        if test is not None and t_us - self._tested_us >= 1000 * test.every_ms:
            rng = self._job_rng(_TEST, t_us)
            quiet = t_us - self._quiet_us <= 1000 * test.quiet_ms
            job = self._submit(_TEST, rotation_flags, problem, omega, moved, config, rng, quiet)
            if self._tested_us == _NEVER:  # no verdict would cover the stream's start: wait
                self._verdict = job.result()
            else:
                self._test_job = job
            self._tested_us = t_us
        if moved >= config.min_motion_px:
            flags |= self._verdict
        return flags

    def _note_quiet(self, t_us: int) -> None:
        """The window at ``t_us`` held too few events: the view is quiet, once the stream is
        older than the longest window (before, the window was short only because it began)."""
        if t_us - self.t0_us >= self.config.window.horizon_us:
            self._quiet_us = t_us

    def _speed(self, omega: np.ndarray) -> float:
        """Image speed (px/s of the objective's binned image) under ω (rad/s)."""
        return pixel_speed(omega, float(self._intrinsics[0]), self._radius) / self._base

    def _update_doubt(self, gain: float, flags: int) -> None:
        """The share of the search interval to wait before the next search. An ill-posed
        estimate, or a gain fallen well below its recent best, may mean that tracking lost the
        motion or slid to a worse local maximum; a collapsed gain (the motion changed
        abruptly) calls for a search at once."""
        if math.isfinite(gain):
            # Best recent gain above 1, forgetting over about 50 estimates.
            self._best_gain = max(gain - 1.0, self._best_gain * 0.98)
        share = (gain - 1.0) / self._best_gain if self._best_gain > 0 else 1.0
        drop = self.config.gain_drop
        self._doubt = 1.0
        if flags or not share >= drop:
            self._doubt = 0.2
        if not share >= 0.5 * drop:
            self._doubt = 0.0

    def _estimate(self, t_us: int, wait: bool = True) -> tuple | None:
        """One estimate at ``t_us`` (the row of an ``Estimates``), or None without events;
        ``wait``: none while the first window is not well posed."""
        searching = self._search_due(t_us)
        window = self._window(t_us, searching)
        if window is None:
            self._note_quiet(t_us)
            return None
        index, span, count = window
        policy = self.config.window
        adaptive = policy.fixed_ms <= 0 and policy.fixed_events <= 0
        if wait and self._omega is None and adaptive and count < policy.posed_events:
            self._note_quiet(t_us)
            return None  # the first estimate waits for a well-posed window: tracking starts there
        buf, config = self._buffer, self.config
        age = (t_us - buf.t[index]) * 1e-6
        delay = float(age.mean())
        width, height = self._sensor
        # Warped to the events' mean time, not to t_us: warping every event to the window's
        # end moves the oldest ones a whole window's motion, where spurious maxima appear
        # (a sparse window's ω found at several times the true rate); the mean rate is the
        # same either way.
        problem = Problem(
            buf.bx[index], buf.by[index], age - delay, np.ones(len(index)), self._intrinsics,
            width, height, self._base,
        )  # fmt: skip
        if searching:
            self._last_search_us, self.searches = t_us, self.searches + 1
        if self._omega is None or (searching and self._doubt == 0.0):
            # Nothing to track from, or tracking lost: a search that is waited for.
            if self._omega is not None:
                self._collapse_us = t_us
            found = self._urgent_search(problem, t_us)
        else:
            if searching:
                self._submit_search(problem, self._omega, t_us)
            found = self._track(problem, self._omega, self._hessian)
            found = self._take_search(problem, found, t_us)
        omega = self._omega = found.omega
        self._hessian = found.inv_hessian
        flat = problem.contrast(np.zeros(3), 1, config.sigma_px)[0]
        gain = found.contrast / flat if flat > 0 else math.nan
        flags = self._flags(problem, omega, count, span, t_us)
        self._update_doubt(gain, flags)
        if config.accelerating:
            omega = self._at_end(t_us, span, omega, delay)
        return t_us, omega, count, span, delay * 1e6, gain, flags

    def _track(
        self, problem: Problem, omega: np.ndarray, inv_hessian: np.ndarray | None
    ) -> Refined:
        """A tracking estimate: a few BFGS steps from ``omega`` (rad/s) at full resolution."""
        config = self.config
        return refine(
            problem, omega, 1, config, config.track_iterations, inv_hessian, config.track_xtol_px
        )

    def _urgent_search(self, problem: Problem, t_us: int) -> Refined:
        """The search of an estimate that cannot wait (see ``CMaxConfig.search_in_line``)."""
        config, omega = self.config, self._omega
        if config.search_in_line:
            self._search_job = None
            return search(problem, config, omega, grid=True, rng=self._rng)
        # No grid points: ω = 0 and the tracked ω, coarse to fine.
        local = replace(config, starts=0, iterations=config.urgent_iterations)
        found = search(problem, local, omega, grid=True, rng=self._rng)
        if self._search_job is None:  # a pending one is kept: where the gain keeps
            self._submit_search(problem, found.omega, t_us)  # collapsing, each would be wasted
        return found

    def _submit_search(self, problem: Problem, omega: np.ndarray, t_us: int) -> None:
        """The global search of ``problem`` (warm start ``omega``, rad/s) on the searches'
        thread, its result due at the first estimate ``search_lag_ms`` after ``t_us``."""
        rng = self._job_rng(_SEARCH, t_us)
        job = self._submit(_SEARCH, search, problem, self.config, omega, True, rng)
        self._search_job = (job, t_us + round(1000 * self.config.search_lag_ms))

    def _take_search(self, problem: Problem, tracked: Refined, t_us: int) -> Refined:
        """``tracked``, or the pending search's ω refined on ``problem`` where its lag is up
        at ``t_us`` and it sharpens the window more."""
        if self._search_job is None or t_us < self._search_job[1]:
            return tracked
        found = self._search_job[0].result()
        self._search_job = None
        candidate = self._track(problem, found.omega, None)
        return candidate if candidate.contrast > tracked.contrast else tracked

    def _submit(self, kind: int, function: Callable[..., Any], *args: Any) -> Future:
        """``function(*args)`` on the thread of jobs of ``kind`` (started at its first job)."""
        if kind not in self._workers:
            init = _lowest_priority if kind == _SEARCH else None
            name = "cmax-search" if kind == _SEARCH else "cmax-test"
            self._workers[kind] = ThreadPoolExecutor(1, name, initializer=init)
        return self._workers[kind].submit(function, *args)

    def _job_rng(self, kind: int, t_us: int) -> np.random.Generator:
        """The subsampling generator of a worker job of ``kind`` at ``t_us``: its own, so that
        jobs never share one with the main thread."""
        return np.random.default_rng((self.config.seed, kind, t_us))

    def _at_end(self, t_us: int, span_us: float, omega: np.ndarray, age_s: float) -> np.ndarray:
        """ω (rad/s) at ``t_us`` under a linearly changing rate, fitted to the events of
        ``bend_window`` times the window's span ``span_us`` (the bend that α puts in the warp
        grows with the square of the span: over one window sized for a few pixels of motion
        it is a fraction of a pixel), from the window's mean rate ``omega`` (the rate at the
        events' mean age ``age_s``, s) and the previous α."""
        buf, config = self._buffer, self.config
        t = buf.times()
        i1 = int(np.searchsorted(t, t_us, side="right"))
        i0 = int(np.searchsorted(t, math.ceil(t_us - config.bend_window * span_us), "left"))
        index = self._kept(i0, i1)
        if index is None:
            return omega
        width, height = self._sensor
        problem = Problem(
            buf.bx[index], buf.by[index], (t_us - buf.t[index]) * 1e-6, np.ones(len(index)),
            self._intrinsics, width, height, self._base,
        )  # fmt: skip
        start = np.r_[omega + self._alpha * age_s, self._alpha]
        found = refine(
            problem,
            start,
            1,
            config,
            config.bend_iterations,
            self._bend_hessian,
            config.track_xtol_px,
            config.bend_cost,
        )
        self._alpha, self._bend_hessian = found.omega[3:], found.inv_hessian
        return found.omega[:3]
