"""The clock offset between a gyro and an event camera, by cross-correlating angular velocities.

An estimator that sees only events (contrast maximization over short windows) gives omega on the
events' clock; the gyro gives omega on its own. For each candidate offset ``d`` (µs, added to the
gyro's timestamps, see :mod:`spikegyro.events.imu`) the gyro's mean over each estimate's sample
times, shifted by ``d``, is compared with the estimates. The sample times are best the times of
events spread evenly through the estimate's window (:func:`event_sample_times`): every event
weighs the same in the contrast, so an estimate is the event-weighted mean of omega, and events
crowd where the motion is fast; a plain time average would bias the offset by a millisecond or
more. The comparison is the normalised cross-correlation of the three axes together (each
axis's mean removed, so a gyro bias does not matter, and normalised, so a scale error such
as a wrong focal length does not either):

    c(d) = sum_i sum_k (e_ik - mean e_i) (g_ik(d) - mean g_i(d))
           / sqrt(sum_ik (e_ik - mean e_i)^2 * sum_ik (g_ik(d) - mean g_i(d))^2)

The best offset maximizes ``c``; a parabola through the best grid point and its neighbours
refines it below the grid step. Only estimates whose windows the gyro covers at every candidate
offset count, so every ``c(d)`` is computed over the same estimates.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from spikegyro.events.core import GyroTrace

MIN_ESTIMATES = 8
"""Fewer estimates than this (inside the gyro's span at every offset) give no fit."""


def offset_grid(max_offset_us: float, step_us: float) -> np.ndarray:
    """Candidate offsets ``-max .. +max`` µs in steps of ``step_us`` (0 always on the grid)."""
    n = int(np.floor(max_offset_us / step_us + 1e-9))
    return np.arange(-n, n + 1) * float(step_us)


def correlation(estimates: np.ndarray, reference: np.ndarray) -> float:
    """Normalised cross-correlation of two (K, 3) series (see the module docstring), unitless in
    [-1, 1]; NaN when either has no variation."""
    e = estimates - estimates.mean(axis=0)
    g = reference - reference.mean(axis=0)
    denom = np.sqrt((e * e).sum() * (g * g).sum())
    return float((e * g).sum() / denom) if denom > 0 else float("nan")


def event_sample_times(
    event_t_us: np.ndarray, starts_us: np.ndarray, ends_us: np.ndarray, count: int = 32
) -> np.ndarray:
    """``count`` event times spread evenly (by index) through each window ``[start, end)``, µs,
    shape (K, count); rows of windows without events are NaN."""
    lo = np.searchsorted(event_t_us, starts_us, side="left")
    hi = np.searchsorted(event_t_us, ends_us, side="left")
    frac = (np.arange(count) + 0.5) / count
    index = (lo[:, None] + frac[None, :] * (hi - lo)[:, None]).astype(np.int64)
    times = event_t_us[np.clip(index, 0, max(len(event_t_us) - 1, 0))].astype(np.float64)
    times[hi <= lo] = np.nan
    return times


def fit_time_offset(
    sample_times_us: np.ndarray,
    estimates: np.ndarray,
    gyro: GyroTrace,
    max_offset_us: float = 30_000.0,
    step_us: float = 250.0,
) -> dict[str, Any]:
    """The gyro-to-events clock offset that best explains ``estimates``.

    Args:
        sample_times_us: (K, M) times (µs, events' clock) whose mean omega each estimate
            measures (:func:`event_sample_times`); rows holding NaN are left out.
        estimates: (K, 3) angular velocity estimates from events, rad/s.
        gyro: the gyro trace (camera frame, its own clock).
        max_offset_us: candidate offsets span ``[-max, +max]`` µs.
        step_us: grid step, µs.

    Returns:
        JSON-ready dict: ``offset_us`` (None when no fit), ``correlation`` at it and
        ``correlation_at_zero``, ``at_edge`` (the best lies on the grid's edge: widen the
        range), ``n_estimates``, the curve ``offsets_us`` / ``correlations`` and ``reason`` when
        no fit was possible.
    """
    times = np.asarray(sample_times_us, dtype=np.float64).reshape(len(estimates), -1)
    grid = offset_grid(max_offset_us, step_us)
    result: dict[str, Any] = {"max_offset_us": float(max_offset_us), "step_us": float(step_us)}
    keep = np.isfinite(estimates).all(axis=1) & np.isfinite(times).all(axis=1)
    if len(gyro) >= 2:
        with np.errstate(invalid="ignore"):
            first, last = times.min(axis=1), times.max(axis=1)
            keep &= (first - grid.max() >= gyro.t[0]) & (last - grid.min() <= gyro.t[-1])
    else:
        keep[:] = False
    result["n_estimates"] = int(keep.sum())
    if keep.sum() < MIN_ESTIMATES:
        return {
            **result,
            "offset_us": None,
            "reason": f"{int(keep.sum())} estimates inside the gyro's span at every offset "
            f"(need {MIN_ESTIMATES}); give a longer recording or a smaller offset range.",
        }
    est, sample = estimates[keep], times[keep]

    def reference(d: float) -> np.ndarray:
        return gyro.interpolate((sample - d).ravel()).reshape(*sample.shape, 3).mean(axis=1)

    curve = np.array([correlation(est, reference(d)) for d in grid])
    if not np.isfinite(curve).any():
        return {
            **result,
            "offset_us": None,
            "reason": "the estimates or the gyro do not vary; the offset is unobservable.",
        }
    i = int(np.nanargmax(curve))
    best = float(grid[i])
    if 0 < i < len(grid) - 1 and np.isfinite(curve[i - 1 : i + 2]).all():
        left, mid, right = curve[i - 1], curve[i], curve[i + 1]
        curvature = left - 2 * mid + right
        if curvature < 0:
            best += 0.5 * (left - right) / curvature * step_us
    zero = int(np.argmin(np.abs(grid)))
    return {
        **result,
        "offset_us": best,
        "correlation": float(curve[i]),
        "correlation_at_zero": float(curve[zero]),
        "at_edge": i in (0, len(grid) - 1),
        "offsets_us": grid.tolist(),
        "correlations": [None if not np.isfinite(c) else float(c) for c in curve],
    }
