"""Event statistics that tell a real sensor from a simulated one (NumPy only, pure functions).

What is measured on one window of events (:func:`window_stats`):

- event rate: events per ms over the window, and events per pixel per second averaged over all
  pixels (``rate_px_hz``) and over the pixels that fired (``active_rate_px_hz``);
- spatial coverage: the share of pixels with at least one event;
- polarity balance: the share of ON events (``on_fraction``);
- hot-pixel share: the share of all events fired by the most active 1 % (and 0.1 %) of the
  sensor's pixels; a few hot pixels on a real sensor push it up;
- inter-event intervals per pixel: the time between consecutive events of the same pixel (either
  polarity), µs; their median and quantiles, and the share shorter than 1 ms (bursts: an edge
  crossing a pixel fires several events in a row; a refractory period removes the shortest).

Distributions (:func:`log_histogram`) use fixed log-spaced bins so that windows and recordings can
be pooled by adding counts. Time is in µs, rates in events per ms or per second as named.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from spikegyro.events.core import EventArray
from spikegyro.events.windows import time_windows

IEI_EDGES_US = np.logspace(0, 6, 61)
"""Inter-event interval bins: 1 µs to 1 s, 10 per decade."""

RATE_EDGES_HZ = np.logspace(-1, 5, 61)
"""Per-pixel event rate bins (events per pixel per second): 0.1 Hz to 100 kHz, 10 per decade."""

TOP_FRACTIONS = (0.001, 0.01)
"""Shares of the most active pixels whose share of events is reported."""


def pixel_counts(events: EventArray) -> np.ndarray:
    """Events per pixel, (height, width) int64."""
    flat = events.y.astype(np.int64) * events.width + events.x.astype(np.int64)
    return np.bincount(flat, minlength=events.width * events.height).reshape(
        events.height, events.width
    )


def top_pixel_share(counts: np.ndarray, fraction: float) -> float:
    """Share of all events fired by the ``fraction`` most active pixels (at least one pixel).

    ``counts`` holds events per pixel (any shape). Uniform activity gives about ``fraction``; one
    hot pixel among quiet ones gives nearly 1. NaN without events.
    """
    flat = np.sort(np.asarray(counts).ravel())[::-1]
    total = flat.sum()
    if total == 0:
        return float("nan")
    k = max(1, round(fraction * flat.size))
    return float(flat[:k].sum() / total)


def inter_event_intervals(events: EventArray) -> np.ndarray:
    """Time between consecutive events of the same pixel (either polarity), µs, int64.

    A pixel with n events contributes n - 1 intervals; the order of the result is by pixel, then
    by time.
    """
    flat = events.y.astype(np.int64) * events.width + events.x.astype(np.int64)
    order = np.lexsort((events.t, flat))
    pix, t = flat[order], events.t[order]
    same = pix[1:] == pix[:-1]
    return (t[1:] - t[:-1])[same]


def log_histogram(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Counts of ``values`` in ``edges`` (int64); values below/above the range go to the first/
    last bin, so nothing is dropped (0 µs intervals land in the first bin)."""
    v = np.clip(np.asarray(values, dtype=np.float64), edges[0], edges[-1])
    return np.histogram(v, bins=edges)[0].astype(np.int64)


def window_stats(events: EventArray, duration_us: float) -> dict[str, Any]:
    """The statistics of one window of ``duration_us`` µs (see the module docstring).

    Returns a JSON-ready dict: ``events``, ``duration_ms``, ``rate_per_ms``, ``rate_px_hz``,
    ``active_rate_px_hz``, ``coverage``, ``on_fraction``, ``top_share`` ({fraction: share}),
    ``iei_median_us``, ``iei_p10_us``, ``iei_p90_us``, ``iei_below_1ms``, and the histograms
    ``iei_hist`` (over :data:`IEI_EDGES_US`) and ``rate_hist`` (per-pixel rates of the pixels
    that fired, over :data:`RATE_EDGES_HZ`). Statistics of an empty set are None.
    """
    if duration_us <= 0:
        raise ValueError(f"duration must be positive, got {duration_us} us")
    n = len(events)
    pixels = events.width * events.height
    counts = pixel_counts(events)
    active = counts[counts > 0]
    seconds = duration_us / 1e6
    iei = inter_event_intervals(events)

    def quantile(q: float) -> float | None:
        return float(np.quantile(iei, q)) if iei.size else None

    return {
        "events": int(n),
        "duration_ms": duration_us / 1000,
        "rate_per_ms": n / (duration_us / 1000),
        "rate_px_hz": n / pixels / seconds,
        "active_rate_px_hz": float(active.mean() / seconds) if active.size else None,
        "coverage": active.size / pixels,
        "on_fraction": float(events.p.mean()) if n else None,
        "top_share": {
            str(f): (None if n == 0 else top_pixel_share(counts, f)) for f in TOP_FRACTIONS
        },
        "iei_median_us": quantile(0.5),
        "iei_p10_us": quantile(0.1),
        "iei_p90_us": quantile(0.9),
        "iei_below_1ms": float((iei < 1000).mean()) if iei.size else None,
        "iei_hist": log_histogram(iei, IEI_EDGES_US).tolist(),
        "rate_hist": log_histogram(active / seconds, RATE_EDGES_HZ).tolist(),
    }


_SCALARS = (
    "rate_per_ms",
    "rate_px_hz",
    "active_rate_px_hz",
    "coverage",
    "on_fraction",
    "iei_median_us",
    "iei_below_1ms",
)


def pool(windows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Combine :func:`window_stats` of several windows.

    Scalars become their distribution over windows (``median``, ``p5``, ``p95``, ``min``,
    ``max``, ``n``; None entries left out), top shares likewise, and the histograms are summed
    (so the pooled intervals weigh every interval equally).
    """
    if not windows:
        raise ValueError("pool needs at least one window")

    def spread(values: list[float | None]) -> dict[str, Any]:
        v = np.array([x for x in values if x is not None], dtype=np.float64)
        if not v.size:
            return {"n": 0}
        q5, q50, q95 = np.quantile(v, [0.05, 0.5, 0.95])
        return {"n": int(v.size), "median": float(q50), "p5": float(q5), "p95": float(q95),
                "min": float(v.min()), "max": float(v.max())}  # fmt: skip

    result: dict[str, Any] = {
        "windows": len(windows),
        "events": int(sum(w["events"] for w in windows)),
        "duration_ms": float(sum(w["duration_ms"] for w in windows)),
    }
    for key in _SCALARS:
        result[key] = spread([w[key] for w in windows])
    result["top_share"] = {
        str(f): spread([w["top_share"][str(f)] for w in windows]) for f in TOP_FRACTIONS
    }
    for key in ("iei_hist", "rate_hist"):
        result[key] = np.sum([w[key] for w in windows], axis=0).astype(np.int64).tolist()
    return result


def split_windows(events: EventArray, window_us: int) -> list[tuple[EventArray, int]]:
    """Consecutive windows ``[t0 + k w, t0 + (k+1) w)`` from the first event's time, with their
    durations (µs); a recording shorter than one window is one window of its own length (last
    event - first + 1 µs), and a partial window at the end is left out."""
    if not len(events):
        return []
    t0 = int(events.t[0])
    span = int(events.t[-1]) - t0 + 1
    if span <= window_us:
        return [(events, span)]
    starts, ends = time_windows(t0, t0 + span, window_us)
    return [
        (events.slice_time(a, b), window_us)
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True)
    ]
