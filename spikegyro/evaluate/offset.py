"""The clock offset between a gyro and an event camera, by cross-correlating angular velocities.

An estimator that sees only events (contrast maximization over short windows) gives omega on the
events' clock; the gyro gives omega on its own. For each candidate offset ``d`` (µs, added to the
gyro's timestamps, see :mod:`spikegyro.events.imu`) the gyro's mean over each estimate's window,
shifted by ``d``, is compared with the estimates by the normalised cross-correlation of the
three axes together (each axis's mean removed, so a gyro bias does not matter, and normalised, so
a scale error such as a wrong focal length does not either):

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
from spikegyro.events.imu import window_means

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


def fit_time_offset(
    starts_us: np.ndarray,
    ends_us: np.ndarray,
    estimates: np.ndarray,
    gyro: GyroTrace,
    max_offset_us: float = 30_000.0,
    step_us: float = 250.0,
) -> dict[str, Any]:
    """The gyro-to-events clock offset that best explains ``estimates``.

    Args:
        starts_us, ends_us: (K,) the windows (µs, events' clock) each estimate averages over.
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
    starts = np.asarray(starts_us, dtype=np.float64)
    ends = np.asarray(ends_us, dtype=np.float64)
    grid = offset_grid(max_offset_us, step_us)
    result: dict[str, Any] = {"max_offset_us": float(max_offset_us), "step_us": float(step_us)}
    keep = np.isfinite(estimates).all(axis=1)
    if len(gyro) >= 2:
        keep &= (starts - grid.max() >= gyro.t[0]) & (ends - grid.min() <= gyro.t[-1])
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
    est, a, b = estimates[keep], starts[keep], ends[keep]
    curve = np.array([correlation(est, window_means(gyro, a - d, b - d)) for d in grid])
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
