"""Per-speed analysis: the metrics within bins of true angular speed (the paper's Figs. 4, 5).

Each evaluated (window, step) pair falls in the bin ``[lo, hi)`` holding its true speed
||omega_hat|| in deg/s. The edges are fixed, not data-driven, so runs on different data or models
stay comparable: :data:`SPEED_BIN_EDGES_DEG_S` = 0, 100, 200, 300, 400, 500, inf deg/s (the
paper's); the last bin is open, so no pair is ever dropped. :data:`FINE_SPEED_BIN_EDGES_DEG_S`
splits the first of them where handheld cameras and robots turn (5-100 deg/s):
``--speed-bins fine`` in ``evaluate`` and ``evaluate-real``.

For the simulator's default rotations (per-axis rates Laplace-distributed with scale 107 deg/s,
mean speed about 225 deg/s) the paper's bins hold about 16, 35, 26, 13, 6 and 4 % of the pairs
(Monte Carlo, 10^6 draws); for Gaussian per-axis rates of mean speed 220 deg/s, 9, 36, 36, 15, 3
and 0.4 %.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.metrics import (
    EVAL_START_STEP,
    MIN_SPEED_DEG_S,
    evaluated_steps,
    summary,
)

SPEED_BIN_EDGES_DEG_S: tuple[float, ...] = (0.0, 100.0, 200.0, 300.0, 400.0, 500.0, math.inf)
FINE_SPEED_BIN_EDGES_DEG_S: tuple[float, ...] = (0.0, 10.0, 25.0, 50.0, *SPEED_BIN_EDGES_DEG_S[1:])
SPEED_BIN_SETS = {"paper": SPEED_BIN_EDGES_DEG_S, "fine": FINE_SPEED_BIN_EDGES_DEG_S}


def parse_speed_bins(text: str) -> tuple[float, ...]:
    """Bin edges (deg/s) from ``paper``, ``fine`` or increasing edges ``0,E1,E2,…`` (an open
    last bin from the last edge on is added, so that no pair is dropped); InputError otherwise."""
    if text in SPEED_BIN_SETS:
        return SPEED_BIN_SETS[text]
    try:
        edges = [float(v) for v in text.split(",")]
    except ValueError:
        edges = []
    if len(edges) < 2 or edges[0] != 0 or any(b <= a for a, b in itertools.pairwise(edges)):
        raise InputError(
            f"--speed-bins {text!r}: give paper, fine or increasing edges in deg/s from 0, "
            "e.g. 0,10,25,50,100"
        )
    return (*edges, *(() if math.isinf(edges[-1]) else (math.inf,)))


def bin_labels(edges: Sequence[float] = SPEED_BIN_EDGES_DEG_S) -> list[str]:
    """Half-open interval labels in deg/s, e.g. ``[100, 200)`` and ``[500, inf)``."""

    def fmt(v: float) -> str:
        return "inf" if math.isinf(v) else f"{v:g}"

    return [f"[{fmt(lo)}, {fmt(hi)})" for lo, hi in itertools.pairwise(edges)]


def speed_bin_index(
    speed_deg_s: np.ndarray, edges: Sequence[float] = SPEED_BIN_EDGES_DEG_S
) -> np.ndarray:
    """Index of the bin ``[edges[i], edges[i+1])`` holding each speed (deg/s); -1 outside all."""
    edges = np.asarray(edges, dtype=np.float64)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"bin edges must increase strictly, got {edges.tolist()}")
    idx = np.searchsorted(edges, np.asarray(speed_deg_s, dtype=np.float64), side="right") - 1
    idx[(idx < 0) | (idx >= edges.size - 1)] = -1
    return idx


def per_bin_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    edges: Sequence[float] = SPEED_BIN_EDGES_DEG_S,
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> list[dict[str, Any]]:
    """The metrics of :func:`spikegyro.metrics.summary` within each speed bin.

    ``pred`` and ``gt`` are (n, T, 3) rad/s; pairs are binned by true speed at their step. Each
    entry holds ``label``, ``lo_deg_s``, ``hi_deg_s`` (None for an open end), ``n_pairs`` and,
    for a non-empty bin, ``median_relative_error``, ``mean_euclidean_error_deg_s``,
    ``rmse_deg_s``, ``n_pairs_relative`` and ``per_axis`` (with the box statistics of the signed
    per-axis relative errors). Empty bins carry only ``n_pairs = 0``.
    """
    p, g = evaluated_steps(pred, gt, start)
    p, g = p.reshape(-1, 3), g.reshape(-1, 3)
    idx = speed_bin_index(np.degrees(np.linalg.norm(g, axis=-1)), edges)
    result = []
    for b, label in enumerate(bin_labels(edges)):
        hi = edges[b + 1]
        entry: dict[str, Any] = {
            "label": label,
            "lo_deg_s": float(edges[b]),
            "hi_deg_s": None if math.isinf(hi) else float(hi),
        }
        mask = idx == b
        entry["n_pairs"] = int(mask.sum())
        if entry["n_pairs"]:
            # One pseudo-window holding the bin's pairs, all of them evaluated (start=0).
            stats = summary(p[mask][None], g[mask][None], 0, min_speed_deg_s)
            entry.update({k: v for k, v in stats.items() if k != "n_pairs"})
        result.append(entry)
    return result


def empty_bins(per_bin: list[dict[str, Any]]) -> list[str]:
    """Labels of the bins without any evaluated pair."""
    return [entry["label"] for entry in per_bin if entry["n_pairs"] == 0]


def bins_json(edges: Sequence[float] = SPEED_BIN_EDGES_DEG_S) -> dict[str, list]:
    """The bins as metrics.json records them: ``edges_deg_s`` (None for the open end, since
    JSON has no infinity) and their ``labels``."""
    return {
        "edges_deg_s": [None if math.isinf(e) else e for e in edges],
        "labels": bin_labels(edges),
    }
