"""Windows of events for contrast maximization, and the clean-up real sensors need.

Windows are index ranges ``[i0, i1)`` into a time-sorted stream, each with a reference time
(µs): the time its events are warped to, and the time its estimate stands for.

- By event count (the usual choice in the CMax literature): every window holds the same number
  of events, so a fast motion gets a short window and a slow one a long window, and the blur
  each window must undo stays about the same. Reference time: the middle of its span.
- By time: fixed duration, centred on the reference time, or ending there (``causal``: the
  estimate uses only past events, as a network's prediction does).
"""

from __future__ import annotations

import numpy as np


def count_windows(t_us: np.ndarray, window_events: int, stride_events: int) -> np.ndarray:
    """Windows of ``window_events`` events every ``stride_events`` events.

    Args:
        t_us: sorted event times, µs.
        window_events: events per window (a stream with fewer gives one window of all of them).
        stride_events: events between the starts of consecutive windows.

    Returns:
        (K, 3) int64 rows ``(i0, i1, t_ref_us)``, t_ref the middle of the window's span. The last
        window ends at the last event, so every event is in some window.
    """
    n = len(t_us)
    if n == 0:
        return np.zeros((0, 3), dtype=np.int64)
    window = min(max(int(window_events), 1), n)
    starts = np.arange(0, n - window + 1, max(int(stride_events), 1), dtype=np.int64)
    if starts[-1] != n - window:
        starts = np.append(starts, n - window)
    ends = starts + window
    t = np.asarray(t_us, dtype=np.int64)
    middle = (t[starts] + t[ends - 1]) // 2
    return np.column_stack([starts, ends, middle])


def time_windows(
    t_us: np.ndarray,
    window_us: int,
    times_us: np.ndarray,
    causal: bool = False,
) -> np.ndarray:
    """Windows of ``window_us`` microseconds at the reference times ``times_us``.

    A window spans ``[t - window_us, t)`` when ``causal``, else ``[t - window_us/2, t +
    window_us/2)``. Returns (K, 3) int64 rows ``(i0, i1, t_ref_us)``.
    """
    times = np.asarray(times_us, dtype=np.int64)
    lead = window_us if causal else window_us // 2
    i0 = np.searchsorted(t_us, times - lead, side="left")
    i1 = np.searchsorted(t_us, times - lead + window_us, side="left")
    return np.column_stack([i0, i1, times]).astype(np.int64)


def hot_pixel_mask(
    x: np.ndarray,
    y: np.ndarray,
    width: int,
    height: int,
    factor: float = 5.0,
    min_count: int = 8,
) -> np.ndarray:
    """Which events to keep: False for events of hot pixels.

    A pixel is hot when it fires more than ``factor`` times the 95th percentile of the counts of
    the pixels that fired, and more than ``min_count`` times. Pixels that an edge sweeps fire a
    few times each, in proportion to the edge's contrast; a hot pixel fires regardless of the
    motion, and its events stay in one place only for the warp of zero motion, so they pull the
    estimate towards ω = 0. Factor <= 0 keeps every event.
    """
    if factor <= 0 or len(x) == 0:
        return np.ones(len(x), dtype=bool)
    index = np.asarray(y, dtype=np.int64) * width + np.asarray(x, dtype=np.int64)
    counts = np.bincount(index, minlength=width * height)
    active = counts[counts > 0]
    threshold = max(float(min_count), factor * float(np.percentile(active, 95)))
    return counts[index] <= threshold
