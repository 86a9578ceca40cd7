"""Per-scene-kind analysis: the metrics within each kind of simulated scene.

A model can do well on average and fail on one kind of scene, e.g. on roll over a few dark shapes
on a plain wall, which is what real indoor recordings such as DAVIS240C ``shapes_rotation`` look
like. The kinds are the simulator's (:data:`spikegyro.sim.dataset.SCENE_KINDS`: sparse shapes,
office, photograph, procedural). Each window takes the kind of its sequence file (attribute
``scene_kind``, derived from the scene's name for files written before it existed, ``unknown``
for files not made by ``spikegyro simulate``; :func:`spikegyro.sim.dataset.scene_kind`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from spikegyro.evaluate.report import Table, fmt
from spikegyro.events.io import read_hdf5_attrs
from spikegyro.metrics import AXES, EVAL_START_STEP, MIN_SPEED_DEG_S, summary
from spikegyro.sim.dataset import SCENE_KINDS, UNKNOWN_SCENE, scene_kind
from spikegyro.train.data import Window


def window_scene_kinds(windows: Sequence[Window]) -> list[str]:
    """The scene kind of each window's sequence file (``Window.source``, an HDF5 file whose
    attributes are read once per file)."""
    kinds: dict[str, str] = {}
    for w in windows:
        if w.source not in kinds:
            kinds[w.source] = scene_kind(read_hdf5_attrs(w.source))
    return [kinds[w.source] for w in windows]


def per_kind_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    kinds: Sequence[str],
    start: int = EVAL_START_STEP,
    min_speed_deg_s: float = MIN_SPEED_DEG_S,
) -> dict[str, dict[str, Any]]:
    """The headline metrics of :func:`spikegyro.metrics.summary` within each kind.

    ``pred`` and ``gt`` are (n, T, 3) rad/s, ``kinds`` one label per window. Returns, for each
    kind present (in the order of :data:`SCENE_KINDS`, then any other label alphabetically):
    ``n_windows``, ``n_pairs`` (evaluated steps), ``median_relative_error`` (unitless; None when
    every true speed is under ``min_speed_deg_s``), ``mean_euclidean_error_deg_s``,
    ``rmse_deg_s`` and ``mean_abs_error_deg_s`` per axis (tilt, pan, roll), in deg/s.
    """
    labels = np.asarray(kinds, dtype=str)
    if labels.shape != (len(pred),):
        raise ValueError(f"need one kind per window: {labels.shape[0]} kinds, {len(pred)} windows")
    rank = {k: i for i, k in enumerate(SCENE_KINDS)}
    result = {}
    for kind in sorted(set(labels.tolist()), key=lambda k: (rank.get(k, len(rank)), k)):
        mask = labels == kind
        stats = summary(pred[mask], gt[mask], start, min_speed_deg_s)
        result[kind] = {
            "n_windows": int(mask.sum()),
            "n_pairs": stats["n_pairs"],
            "median_relative_error": stats["median_relative_error"],
            "mean_euclidean_error_deg_s": stats["mean_euclidean_error_deg_s"],
            "rmse_deg_s": stats["rmse_deg_s"],
            "mean_abs_error_deg_s": {
                axis: stats["per_axis"][axis]["mean_abs_error_deg_s"] for axis in AXES
            },
        }
    return result


def kind_table(entries: Sequence[Mapping[str, Any]]) -> Table | None:
    """One row per scene kind and model entry (``name``, ``per_scene_kind`` of a metrics.json);
    None when no window's kind is known (data not made by ``spikegyro simulate``)."""
    kinds = list(entries[0].get("per_scene_kind") or {}) if entries else []
    if not set(kinds) - {UNKNOWN_SCENE}:
        return None
    header = ["scene", "model", "windows", "median rel. error", "mean Eucl. error"]
    header += [f"{axis} MAE" for axis in AXES]
    rows = []
    for kind in kinds:
        for entry in entries:
            m = entry["per_scene_kind"][kind]
            rows.append(
                [
                    kind,
                    entry["name"],
                    fmt(m["n_windows"]),
                    fmt(m["median_relative_error"]),
                    fmt(m["mean_euclidean_error_deg_s"], 1),
                    *(fmt(m["mean_abs_error_deg_s"][axis], 1) for axis in AXES),
                ]
            )
    return Table(
        f"Per scene kind (steps >= {EVAL_START_STEP}): median relative error; mean Euclidean "
        "error and per-axis mean absolute error (MAE) in deg/s",
        header,
        rows,
    )
