"""Causal windows of events for contrast maximization, and the clean-up real sensors need.

An estimate stamped ``t`` uses the events in ``(t - W, t]``: only the past, as a gyroscope in a
control loop must. The window ``W`` (:class:`WindowPolicy`) adapts to the event rate and to
the motion so that each estimate is well posed:

- enough events: at least ``min_events`` (a window of 1,500 events cannot pin a slow rotation
  down, and the estimate's noise falls with the events behind it: 8,000 by default, chosen by
  the error at each estimate's own time, ``bench/cmax_lag.py``);
- enough image motion: the previous estimate must move edges by ``target_px`` pixels over the
  window (a slow pan needs a long window, a fast roll a short one), so the blur that the warp
  undoes is always a few pixels, the regime where the contrast has a sharp, well-scaled peak;
- bounded by ``min_ms`` and ``max_ms`` (the latency and the constant-ω assumption);
- shorter where the event rate has risen sharply since a long previous window (the motion sped
  up before an estimate could show it: :func:`predicted_speed`).

A window can also be fixed, by time (``fixed_ms``) or by count (``fixed_events``).

The estimate is a mean rate over its window, so it lags the true ω by about the distance from
the events' mean time to ``t`` (about W/2 for a steady event rate): the latency reported with
each estimate.

Hot pixels (:class:`HotPixels`, :func:`hot_pixel_mask`) fire whatever the motion; their events
stay in one place only under the warp of zero motion, so they pull estimates towards ω = 0 and
are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def pixel_speed(omega: np.ndarray, fx: float, radius_px: float) -> float:
    """Typical image speed (px/s) under rotation ω (rad/s): ``fx |ω_xy|`` from tilt and pan,
    ``radius_px |ω_z|`` from roll (``radius_px``: the RMS distance of the sensor's pixels from
    the principal point, where roll moves them)."""
    w = np.asarray(omega, dtype=np.float64)
    return math.hypot(fx * math.hypot(w[0], w[1]), radius_px * abs(w[2]))


def rms_radius(width: int, height: int, cx: float, cy: float) -> float:
    """RMS distance (px) of a ``width`` x ``height`` sensor's pixel centres from (cx, cy)."""
    mean_x, mean_y = (width - 1) / 2.0, (height - 1) / 2.0
    var = (width**2 - 1) / 12.0 + (height**2 - 1) / 12.0
    return math.sqrt(var + (mean_x - cx) ** 2 + (mean_y - cy) ** 2)


@dataclass(frozen=True)
class WindowPolicy:
    """How long a causal window is (see the module).

    Attributes:
        min_events: adaptive windows hold at least this many events (when the last ``max_ms``
            have that many).
        well_posed_events: an adaptive window holding fewer events than this, or than
            ``min_events`` where that is fewer (it reached ``max_ms`` first), gives an estimate
            flagged ill-posed (``ill_posed`` bit 1), and a stream's first estimate waits for
            that many.
        target_px: ... and are long enough that the previous estimate moves edges this far, px.
        count_reach: ... but ``min_events`` lengthen a window to at most this many times what
            ``target_px`` asks for: where the event rate falls (a fast rotation stopping), the
            last ``min_events`` reach back into the earlier motion.
        min_ms, max_ms: bounds of adaptive windows, ms.
        fixed_ms: > 0: every window lasts this long instead (ms).
        fixed_events: > 0: every window holds the last this many events instead.
        search_ms: an adaptive window that starts a global search (no estimate to size it
            by, or one in doubt) lasts at least this long, so that a rotation of a few deg/s
            moves edges enough to be found.
        rate_events: the recent event rate (:func:`event_rate`, :func:`predicted_speed`) is
            measured over at least this many of the newest events (0: windows are not sized
            by the event rate) ...
        rate_share: ... and over at least this share of the previous window's span.
        rate_rise: a recent event rate up to this many times that of the previous window is
            taken for the texture in view, not for a faster motion (:func:`predicted_speed`).
        rate_min_ms: only a previous window at least this long is shortened by the event rate.
            A window of a few output periods lags an acceleration by a few estimates at most,
            and the rate over a quarter of it, a few ms, is too unsteady on a real sensor: on
            a real roll played on a 1200x900 sensor at 5 M events/s, shortening windows of any
            length let the estimates run away to 1,000 deg/s.
    """

    min_events: int = 8000
    well_posed_events: int = 3000
    target_px: float = 10.0
    count_reach: float = 3.0
    min_ms: float = 2.0
    max_ms: float = 300.0
    fixed_ms: float = 0.0
    fixed_events: int = 0
    search_ms: float = 30.0
    rate_events: int = 500
    rate_share: float = 0.25
    rate_rise: float = 1.5
    rate_min_ms: float = 40.0

    @property
    def posed_events(self) -> int:
        """Events that make an adaptive window well posed: ``well_posed_events``, or
        ``min_events`` where that is fewer."""
        return min(self.min_events, self.well_posed_events)

    @property
    def horizon_us(self) -> int:
        """How far back (µs) a window may reach; events older than this can be forgotten.
        Count windows reach back as far as their events go, bounded by ``max_ms``."""
        return round(1000 * (self.fixed_ms if self.fixed_ms > 0 else self.max_ms))

    def start(
        self,
        t_us: np.ndarray,
        i1: int,
        t_ref_us: int,
        speed_px_s: float | None,
        searching: bool = False,
    ) -> int:
        """Index of the window's first event among sorted times ``t_us`` whose window ends
        after index ``i1 - 1`` at ``t_ref_us``; ``speed_px_s``: image speed of the previous
        estimate (None: none yet); ``searching``: the window is for a global search."""
        if self.fixed_events > 0:
            i0 = max(i1 - self.fixed_events, 0)
            lo = int(np.searchsorted(t_us, t_ref_us - self.horizon_us, side="right"))
            return max(i0, lo)
        if self.fixed_ms > 0:
            window_us = 1000.0 * self.fixed_ms
        else:
            by_count = 0.0
            if i1 > 0:
                first = max(i1 - self.min_events, 0)
                by_count = float(t_ref_us - t_us[first]) + 1.0
            by_motion = 0.0
            if speed_px_s is not None and speed_px_s > 0:
                by_motion = 1e6 * self.target_px / speed_px_s
                by_count = min(by_count, self.count_reach * by_motion)
            shortest = max(self.min_ms, self.search_ms if searching else 0.0)
            window_us = min(max(by_count, by_motion, 1000.0 * shortest), 1000.0 * self.max_ms)
        # An integer bound: a float one would convert every buffered time to float first.
        return int(np.searchsorted(t_us, math.floor(t_ref_us - window_us), side="right"))


def event_rate(t_us: np.ndarray, i0: int, i1: int) -> float:
    """Events per second of the sorted times ``t_us[i0:i1]`` (µs): 0 for fewer than 2 events.
    Counted from the first event to the last, so that it does not depend on where the span
    is cut."""
    if i1 - i0 < 2:
        return 0.0
    return (i1 - i0 - 1) * 1e6 / max(float(t_us[i1 - 1] - t_us[i0]), 1.0)


def predicted_speed(
    speed_px_s: float, rate_now: float, rate_then: float, rate_rise: float = 1.5
) -> float:
    """Image speed (px/s) now from ``speed_px_s``, the previous estimate's, scaled by how much
    the event rate has risen since beyond ``rate_rise``: by ``rate_now / (rate_rise *
    rate_then)`` where that exceeds 1 (``rate_now``: the recent rate; ``rate_then``: that of
    the previous estimate's window; events/s).

    A scene's event rate grows with the speed of its edges, so a sharp rise means the motion
    sped up since the previous estimate, and the window for the motion target must shrink now,
    not an estimate later: a window sized by the old speed gives the old, slow rate again,
    which sizes the next window, and the estimates lag an acceleration by many windows. The
    rate also varies with the texture in view and comes in bursts; a rise within ``rate_rise``
    is taken for that. A fall is left to the estimates: the event rate also falls where the
    view turns to a plainer part of the scene."""
    if rate_then > 0 and rate_now > rate_rise * rate_then:
        return speed_px_s * rate_now / (rate_rise * rate_then)
    return speed_px_s


class EventBuffer:
    """The recent events of a stream as rays, appended in amortized O(batch), forgotten from
    the front: t (µs, int64), ray x/z and y/z (float64), flat pixel index (int32)."""

    def __init__(self, capacity: int = 1 << 16) -> None:
        self.t = np.zeros(capacity, np.int64)
        self.bx = np.zeros(capacity)
        self.by = np.zeros(capacity)
        self.pix = np.zeros(capacity, np.int32)
        self.start = 0
        self.end = 0

    def __len__(self) -> int:
        return self.end - self.start

    def append(self, t: np.ndarray, bx: np.ndarray, by: np.ndarray, pix: np.ndarray) -> None:
        """Add events (already time-ordered after the buffered ones)."""
        n = len(t)
        if self.end + n > len(self.t):
            live = self.end - self.start
            capacity = max(len(self.t), 2 * (live + n))
            for name in ("t", "bx", "by", "pix"):
                old = getattr(self, name)
                new = old if capacity == len(old) else np.zeros(capacity, old.dtype)
                # Move the live part to the front (overlapping copy is safe with a temporary).
                new[:live] = old[self.start : self.end].copy()
                setattr(self, name, new)
            self.start, self.end = 0, live
        s = slice(self.end, self.end + n)
        self.t[s], self.bx[s], self.by[s], self.pix[s] = t, bx, by, pix
        self.end += n

    def forget_before(self, t_us: int) -> None:
        """Drop the events older than ``t_us`` (µs)."""
        self.start += int(np.searchsorted(self.t[self.start : self.end], t_us, side="left"))

    def times(self) -> np.ndarray:
        """The buffered times (a view)."""
        return self.t[self.start : self.end]


class Thinning:
    """Keeps at most about ``rate`` events per second of a stream, so that the work per event
    (rays, buffering, hot-pixel counts) stops growing with the event rate.

    Time is cut into slots of ``slot_us``; the events of a slot keep every k-th event of the
    stream (by its index in the stream), k = ceil(events of the previous slot / the slot's
    share of ``rate``), 1 after an empty slot. It depends on the events only, not on how they
    were batched, and keeps the same share of every part of a slot, as the evenly thinned
    windows do. A rate <= 0 keeps every event.
    """

    def __init__(self, rate: float, slot_us: int = 10_000) -> None:
        self.budget = rate * slot_us / 1e6
        self.slot_us = slot_us
        self.slot: int | None = None
        self.count = 0  # events of the current slot so far
        self.previous = 0  # events of the slot before it
        self.seen = 0  # events so far: the stream index of the next one

    def keep(self, t_us: np.ndarray) -> np.ndarray | None:
        """Indices of the events to keep of a batch with times ``t_us`` (µs, sorted, after all
        earlier batches); None: all of them."""
        n = len(t_us)
        if self.budget <= 0 or n == 0:
            self.seen += n
            return None
        parts, a = [], 0
        while a < n:
            # The batch's slots by binary search, not by dividing every time: at 10 M events/s
            # that division cost a tenth of a core.
            slot = int(t_us[a]) // self.slot_us
            b = int(np.searchsorted(t_us, (slot + 1) * self.slot_us, side="left"))
            if slot != self.slot:
                follows = self.slot is not None and slot == self.slot + 1
                self.previous, self.slot, self.count = (self.count if follows else 0), slot, 0
            k = max(1, math.ceil(self.previous / self.budget))
            first = a + (-(self.seen + a)) % k  # the first index in [a, b) that k divides
            parts.append(np.arange(first, b, k))
            self.count += b - a
            a = b
        self.seen += n
        kept = np.concatenate(parts)
        return None if len(kept) == n else kept


class HotPixels:
    """Streaming hot-pixel detector: per-pixel event counts decaying with ``tau_s``.

    A pixel is hot when its count exceeds ``factor`` times the 95th percentile of the counts of
    the pixels that fired in the latest batch, and ``min_count`` (as :func:`hot_pixel_mask` on
    a window); the threshold is recomputed every ``every_s`` of event time. Factor <= 0 marks
    none.

    Every operation costs O(batch), none O(pixels) (a megapixel's worth per batch would cost
    more than the rest of the engine): counts are kept in units of a reference time and a batch
    adds exp(its age / tau), so nothing decays the array but a rescale when those units grow
    past 1e100 (every minute or so); the threshold is kept in the same units.
    """

    def __init__(
        self,
        pixels: int,
        factor: float = 5.0,
        tau_s: float = 0.5,
        min_count: float = 8.0,
        every_s: float = 0.05,
    ) -> None:
        self.counts = np.zeros(pixels)
        self.factor, self.tau_us, self.min_count = factor, tau_s * 1e6, min_count
        self.every_us = every_s * 1e6
        self._reference_us: int | None = None
        self._checked_at: int | None = None
        self._threshold = math.inf  # in the counts' units

    def add(self, pix: np.ndarray, t_last_us: int) -> None:
        """Count a batch of events (flat pixel indices) ending at ``t_last_us``."""
        if self.factor <= 0 or not len(pix):
            return
        if self._reference_us is None:
            self._reference_us = t_last_us
        scale = math.exp((t_last_us - self._reference_us) / self.tau_us)
        if scale > 1e100:
            self.counts /= scale
            self._threshold /= scale
            self._reference_us, scale = t_last_us, 1.0
        np.add.at(self.counts, pix, scale)
        if self._checked_at is not None and t_last_us - self._checked_at < self.every_us:
            return
        self._checked_at = t_last_us
        fired = self.counts[np.unique(pix)] / scale
        threshold = max(self.min_count, self.factor * float(np.percentile(fired, 95)))
        self._threshold = threshold * scale

    def is_hot(self, pix: np.ndarray) -> np.ndarray:
        """Whether each of the flat pixel indices ``pix`` is hot (bool, same shape)."""
        return self.counts[pix] > self._threshold

    @property
    def hot(self) -> np.ndarray:
        """Every pixel's verdict (bool, O(pixels))."""
        return self.counts > self._threshold


def hot_pixel_mask(
    x: np.ndarray,
    y: np.ndarray,
    width: int,
    height: int,
    factor: float = 5.0,
    min_count: int = 8,
) -> np.ndarray:
    """Which events of one window to keep: False for events of hot pixels.

    A pixel is hot when it fires more than ``factor`` times the 95th percentile of the counts of
    the pixels that fired, and more than ``min_count`` times. Pixels that an edge sweeps fire a
    few times each, in proportion to the edge's contrast; a hot pixel fires regardless of the
    motion. Factor <= 0 keeps every event.
    """
    if factor <= 0 or len(x) == 0:
        return np.ones(len(x), dtype=bool)
    index = np.asarray(y, dtype=np.int64) * width + np.asarray(x, dtype=np.int64)
    counts = np.bincount(index, minlength=width * height)
    active = counts[counts > 0]
    threshold = max(float(min_count), factor * float(np.percentile(active, 95)))
    return counts[index] <= threshold
