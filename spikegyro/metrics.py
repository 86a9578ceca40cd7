"""The paper's error metrics, as pure functions of prediction and ground-truth arrays.

Every function takes ``pred`` and ``gt`` of shape (n, T, 3): n windows of T one-millisecond steps,
angular velocity (tilt, pan, roll) = (omega_x, omega_y, omega_z) in **rad/s**. Only steps
``k >= start`` count (default 50: the SNN's settling time, as in the paper's training and test).
Results are reported in **deg/s** (absolute errors) or as unitless ratios (relative errors).

Names are honest: the paper's table says "RMSE" but its code computes the *mean* Euclidean error
(:func:`mean_euclidean_error`); the true root-mean-square error is :func:`rmse` (always >= the
mean). The paper's "relative error" is the median over (window, step) pairs of
||omega - omega_hat|| / ||omega_hat||, leaving out pairs whose true speed is under 1 deg/s
(:func:`median_relative_error`).

Per-window metrics (:func:`window_metrics`) compare *means over 20 ms sub-windows* instead of
single milliseconds, so a per-ms SNN and an ANN that predicts one mean per 20 ms window compete
on the ANN's terms too. The sub-windows are ``[j * 20, (j + 1) * 20)`` ms from the window start (the
ANNs' ``target_ms`` windows, see :func:`spikegyro.train.data.encode_target`) that lie wholly in
the evaluated steps: for 100 ms windows and ``start = 50``, ``[60, 80)`` and ``[80, 100)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

EVAL_START_STEP = 50
"""First step (ms) of each 100-step window that enters the metrics."""

MIN_SPEED_DEG_S = 1.0
"""Pairs (and, per axis, components) with a true value below this (deg/s) are left out of
relative errors, which are unbounded as the true value goes to zero."""

WINDOW_METRIC_MS = 20
"""Sub-window length (ms) of :func:`window_metrics`: the paper's ANN window."""

AXES = ("tilt", "pan", "roll")
"""Names of the three components omega_x, omega_y, omega_z (camera x right, y down, z forward)."""


def evaluated_steps(pred: np.ndarray, gt: np.ndarray, start: int = EVAL_START_STEP) -> tuple:
    """Check shapes and return ``(pred, gt)`` restricted to steps ``k >= start``, float64 rad/s.

    Raises:
        ValueError: if shapes differ or are not (n, T, 3), if T <= start, or if a value is not
            finite (a method that cannot predict must say so before the metrics, not with NaN).
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[2] != 3:
        raise ValueError(f"pred and gt must both be (n, T, 3); got {pred.shape} and {gt.shape}")
    if pred.shape[1] <= start:
        raise ValueError(f"windows have {pred.shape[1]} steps; metrics need more than {start}")
    if not (np.isfinite(pred).all() and np.isfinite(gt).all()):
        raise ValueError("pred and gt must be finite")
    return pred[:, start:], gt[:, start:]


def euclidean_errors_deg(pred: np.ndarray, gt: np.ndarray, start: int = EVAL_START_STEP):
    """||omega - omega_hat|| per (window, step), deg/s, shape (n, T - start)."""
    p, g = evaluated_steps(pred, gt, start)
    return np.degrees(np.linalg.norm(p - g, axis=-1))


def mean_euclidean_error(pred: np.ndarray, gt: np.ndarray, start: int = EVAL_START_STEP) -> float:
    """Mean over (window, step) of ||omega - omega_hat||, deg/s: the paper's "RMSE"."""
    return float(euclidean_errors_deg(pred, gt, start).mean())


def rmse(pred: np.ndarray, gt: np.ndarray, start: int = EVAL_START_STEP) -> float:
    """True root-mean-square error sqrt(mean ||omega - omega_hat||^2) over (window, step), deg/s.

    Equals sqrt(rmse_tilt^2 + rmse_pan^2 + rmse_roll^2).
    """
    return float(np.sqrt(np.mean(euclidean_errors_deg(pred, gt, start) ** 2)))


def relative_errors(
    pred: np.ndarray,
    gt: np.ndarray,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> np.ndarray:
    """||omega - omega_hat|| / ||omega_hat|| for every (window, step) with ||omega_hat|| >=
    ``min_speed_deg_s``; a flat array (window-major, then step) of unitless ratios."""
    p, g = evaluated_steps(pred, gt, start)
    speed = np.linalg.norm(g, axis=-1)
    keep = speed >= np.radians(min_speed_deg_s)
    return np.linalg.norm(p - g, axis=-1)[keep] / speed[keep]


def median_relative_error(
    pred: np.ndarray,
    gt: np.ndarray,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> float | None:
    """The paper's "relative error": median of :func:`relative_errors`; None if no pair is left."""
    rel = relative_errors(pred, gt, start, min_speed_deg_s)
    return float(np.median(rel)) if rel.size else None


def axis_relative_errors(
    pred: np.ndarray,
    gt: np.ndarray,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> list[np.ndarray]:
    """Signed per-axis relative errors (omega_i - omega_hat_i) / |omega_hat_i| (the paper's
    Figure 5), one flat array per axis (tilt, pan, roll), unitless.

    Positive means the prediction is larger (more positive) than the truth. Components with
    |omega_hat_i| under ``min_speed_deg_s`` are left out.
    """
    p, g = evaluated_steps(pred, gt, start)
    out = []
    for i in range(3):
        mag = np.abs(g[..., i])
        keep = mag >= np.radians(min_speed_deg_s)
        out.append((p[..., i] - g[..., i])[keep] / mag[keep])
    return out


def box_stats(values: np.ndarray, label: str = "") -> dict[str, Any]:
    """Tukey box-plot statistics of ``values`` (JSON-ready; the keys matplotlib's ``bxp`` reads).

    Whiskers reach the most extreme data within 1.5 IQR of the quartiles. Empty input gives
    ``{"label": label, "n": 0}``.
    """
    values = np.asarray(values, dtype=np.float64).ravel()
    if values.size == 0:
        return {"label": label, "n": 0}
    q1, med, q3 = np.percentile(values, [25, 50, 75])
    iqr = q3 - q1
    inside = values[(values >= q1 - 1.5 * iqr) & (values <= q3 + 1.5 * iqr)]
    return {
        "label": label,
        "n": int(values.size),
        "q1": float(q1),
        "med": float(med),
        "q3": float(q3),
        "whislo": float(inside.min()),
        "whishi": float(inside.max()),
        "mean": float(values.mean()),
    }


def axis_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> dict[str, dict[str, Any]]:
    """Per axis: mean absolute error and RMSE (deg/s), and the signed relative error's box stats
    plus the median of its magnitude (unitless)."""
    p, g = evaluated_steps(pred, gt, start)
    err = np.degrees(p - g)
    rel = axis_relative_errors(pred, gt, start, min_speed_deg_s)
    result = {}
    for i, axis in enumerate(AXES):
        result[axis] = {
            "mean_abs_error_deg_s": float(np.abs(err[..., i]).mean()),
            "rmse_deg_s": float(np.sqrt(np.mean(err[..., i] ** 2))),
            "median_abs_relative_error": float(np.median(np.abs(rel[i]))) if rel[i].size else None,
            "relative_error": box_stats(rel[i], axis),
        }
    return result


def summary(
    pred: np.ndarray,
    gt: np.ndarray,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> dict[str, Any]:
    """All overall metrics as a JSON-ready dict (see the module docstring for the definitions)."""
    p, _ = evaluated_steps(pred, gt, start)
    rel = relative_errors(pred, gt, start, min_speed_deg_s)
    return {
        "median_relative_error": float(np.median(rel)) if rel.size else None,
        "mean_euclidean_error_deg_s": mean_euclidean_error(pred, gt, start),
        "rmse_deg_s": rmse(pred, gt, start),
        "n_pairs": int(p.shape[0] * p.shape[1]),
        "n_pairs_relative": int(rel.size),
        "per_axis": axis_metrics(pred, gt, start, min_speed_deg_s),
    }


def sub_windows(
    num_steps: int, window_ms: int = WINDOW_METRIC_MS, start: int = EVAL_START_STEP
) -> list[tuple[int, int]]:
    """The sub-windows ``[a, b)`` (steps = ms from the window start) of :func:`window_metrics`.

    They are aligned with the window start (``a`` a multiple of ``window_ms``) and lie wholly in
    ``[start, num_steps)``; a partial sub-window at either end is left out.
    """
    if window_ms <= 0:
        raise ValueError(f"window_ms must be positive, got {window_ms}")
    first = -(-start // window_ms)  # the first aligned sub-window starting at or after `start`
    return [(j * window_ms, (j + 1) * window_ms) for j in range(first, num_steps // window_ms)]


def window_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    window_ms: int = WINDOW_METRIC_MS,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> dict[str, Any]:
    """Errors of the mean prediction against the mean truth over each :func:`sub_windows`.

    ``pred`` and ``gt`` are (n, T, 3) rad/s. Each (window, sub-window) pair contributes one
    error between the two means, and the statistics are those of :func:`summary`: median
    relative error (unitless; pairs whose mean true speed is under ``min_speed_deg_s`` left out),
    mean Euclidean error and RMSE (deg/s). JSON-ready dict; the metrics are None when no
    sub-window fits in the evaluated steps.
    """
    p, g = evaluated_steps(pred, gt, start)
    bounds = sub_windows(start + p.shape[1], window_ms, start)
    result: dict[str, Any] = {"window_ms": window_ms, "sub_windows_ms": [list(b) for b in bounds]}
    if not bounds:
        return {
            **result,
            "median_relative_error": None,
            "mean_euclidean_error_deg_s": None,
            "rmse_deg_s": None,
            "n_windows": 0,
            "n_windows_relative": 0,
        }
    p_mean = np.stack([p[:, a - start : b - start].mean(axis=1) for a, b in bounds], axis=1)
    g_mean = np.stack([g[:, a - start : b - start].mean(axis=1) for a, b in bounds], axis=1)
    rel = relative_errors(p_mean, g_mean, 0, min_speed_deg_s)
    return {
        **result,
        "median_relative_error": float(np.median(rel)) if rel.size else None,
        "mean_euclidean_error_deg_s": mean_euclidean_error(p_mean, g_mean, 0),
        "rmse_deg_s": rmse(p_mean, g_mean, 0),
        "n_windows": int(p_mean.shape[0] * p_mean.shape[1]),
        "n_windows_relative": int(rel.size),
    }
