"""Windows over an event stream's clock, and per-ms series averaged over them.

A window is a half-open span ``[start, end)`` of microseconds. Windows are tiled either by time
(:func:`time_windows`: whole windows of a fixed length, a partial one at the end left out) or by
event count (:func:`event_windows`); :func:`bin_means` averages a per-millisecond series (a
model's omega per 1 ms step) over any windows, so a model that answers every millisecond can be
compared with one that answers once per window; :func:`series_per_window` gathers a
method's per-ms series over a list of windows.

The module depends on NumPy alone, so evaluation, the baselines and the event tools can share
it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from spikegyro.errors import check_interrupt

BIN_US = 1000
"""Length of one step of a per-ms series, µs."""


def time_windows(begin_us: int, end_us: int, length_us: float) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive whole windows ``[a, a + length)`` from ``begin_us`` up to ``end_us`` (µs).

    Returns ``(starts, ends)``, int64 µs; window ``k`` spans ``begin + round(k length)`` to
    ``begin + round((k + 1) length)``, so a fractional length does not drift. A partial window
    at the end is left out; none when ``end_us <= begin_us``.
    """
    count = int((end_us - begin_us) // length_us) if end_us > begin_us else 0
    starts = begin_us + np.round(np.arange(count) * length_us).astype(np.int64)
    ends = begin_us + np.round(np.arange(1, count + 1) * length_us).astype(np.int64)
    return starts, ends


def event_windows(
    t_us: np.ndarray, begin_us: int, end_us: int, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive windows of exactly ``count`` events among those in ``[begin_us, end_us)``;
    each spans from its first event's time to just after its last (µs). ``t_us`` is sorted;
    the events left over at the end make no window."""
    i0, i1 = np.searchsorted(t_us, [begin_us, end_us], side="left")
    firsts = np.arange(int(i0), int(i1) - count + 1, count, dtype=np.int64)
    return t_us[firsts], t_us[firsts + count - 1] + 1


def bin_means(
    values: np.ndarray, t0_us: int, starts_us: np.ndarray, ends_us: np.ndarray
) -> np.ndarray:
    """Mean of a per-ms series over each ``[start, end)`` µs, each step k taken as constant over
    ``[t0 + k ms, t0 + (k+1) ms)`` (overlap-weighted); (n, 3), the units of ``values``.

    Times outside the series are clipped to it; a zero-length window gives 0.
    """
    cumulative = np.concatenate([np.zeros((1, 3)), np.cumsum(values, axis=0)])

    def integral(t_us: np.ndarray) -> np.ndarray:
        x = np.clip((np.asarray(t_us, dtype=np.float64) - t0_us) / BIN_US, 0, len(values))
        k = np.minimum(np.floor(x).astype(np.int64), len(values) - 1)
        return cumulative[k] + (x - k)[:, None] * values[k]

    span = (np.asarray(ends_us, dtype=np.float64) - starts_us)[:, None] / BIN_US
    return (integral(ends_us) - integral(starts_us)) / np.maximum(span, 1e-12)


W = TypeVar("W")


def series_per_window(
    predict: Callable[[Sequence[W]], np.ndarray],
    windows: Sequence[W],
    num_steps: int,
    batch_size: int = 1,
    progress: Callable[[int], Any] | None = None,
    dtype: type = np.float64,
) -> np.ndarray:
    """Per-ms series (n, num_steps, 3) of ``windows``, in the units ``predict`` gives.

    ``predict`` maps a batch of at most ``batch_size`` consecutive windows to their
    (batch, num_steps, 3) series; ``progress(done)`` is called with the windows done after each.
    """
    out = np.zeros((len(windows), num_steps, 3), dtype=dtype)
    for i in range(0, len(windows), batch_size):
        batch = windows[i : i + batch_size]
        check_interrupt()
        out[i : i + len(batch)] = predict(batch)
        if progress is not None:
            progress(i + len(batch))
    return out
