"""Figures drawn from metric results (not from raw predictions), so `report` can redraw any run.

Each model keeps one color in every figure (:func:`model_color`, a fixed palette keyed by the
model's display name); each axis keeps one color too (:data:`AXIS_COLORS`). Figures are built on
``matplotlib.figure.Figure`` directly (no pyplot global state) and saved as PNG without metadata,
so the same results give the same bytes.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from spikegyro.events.io import atomic_path
from spikegyro.metrics import AXES

# Okabe-Ito colors (distinguishable with the common color-vision deficiencies).
MODEL_COLORS: dict[str, str] = {
    "SNN-6": "#D55E00",
    "SNN-6 (official)": "#CC79A7",
    "ANN-6": "#0072B2",
    "ResNet-50 (A)": "#56B4E9",
    "ResNet-50 (V)": "#009E73",
    "CMax": "#E69F00",
    "Mean": "#7F7F7F",
}
_EXTRA_COLORS = ("#000000", "#8C564B", "#BCBD22", "#17BECF", "#9467BD", "#F0E442")

AXIS_COLORS: dict[str, str] = {"tilt": "#1F77B4", "pan": "#2CA02C", "roll": "#D62728"}
AXIS_SYMBOLS = {"tilt": "ω_x", "pan": "ω_y", "roll": "ω_z"}

DPI = 120
BOX_CLIP = 2.0
"""Largest |relative error| shown in the box plots: slow components make whiskers huge."""


def _mark_empty(ax: Any, per_bin_lists: Sequence[Sequence[Mapping[str, Any]]]) -> None:
    """Write "no data" in the middle of each bin slot that is empty in every list."""
    for i, bins in enumerate(zip(*per_bin_lists, strict=True)):
        if all(b["n_pairs"] == 0 for b in bins):
            ax.text(i, 0.8, "no data", transform=ax.get_xaxis_transform(), ha="center",
                    va="center", fontsize=9, color="#555555")  # fmt: skip


def model_color(name: str) -> str:
    """The fixed color of model ``name``; unknown names get a stable color from their hash."""
    if name in MODEL_COLORS:
        return MODEL_COLORS[name]
    return _EXTRA_COLORS[zlib.crc32(name.encode()) % len(_EXTRA_COLORS)]


def save_figure(fig: Figure, path: str | os.PathLike) -> Path:
    """Write ``fig`` as a metadata-free PNG atomically; returns the path."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=DPI, format="png", metadata={"Software": None})
    return path


def median_relative_error_per_bin(
    per_bin_by_model: Mapping[str, Sequence[Mapping[str, Any]]],
    title: str = "Median relative error per speed bin",
) -> Figure:
    """Grouped bars: the median relative error of each model in each speed bin (paper Fig. 4).

    Args:
        per_bin_by_model: model name -> the list from
            :func:`spikegyro.evaluate.bins.per_bin_metrics` (all with the same bins).
    """
    names = list(per_bin_by_model)
    first = per_bin_by_model[names[0]]
    labels = [b["label"] for b in first]
    fig = Figure(figsize=(min(13.0, 5.5 + len(labels) * (0.5 + 0.2 * len(names))), 4.4))
    ax = fig.add_subplot()
    width = 0.8 / len(names)
    x = np.arange(len(labels))
    top = 0.0
    for j, name in enumerate(names):
        values = [b.get("median_relative_error") for b in per_bin_by_model[name]]
        heights = [np.nan if v is None else v for v in values]
        top = max(top, np.nanmax(heights) if not np.all(np.isnan(heights)) else 0.0)
        ax.bar(
            x - 0.4 + width * (j + 0.5),
            heights,
            width,
            label=name,
            color=model_color(name),
            edgecolor="black",
            linewidth=0.5,
        )
    _mark_empty(ax, list(per_bin_by_model.values()))
    counts = {tuple(b["n_pairs"] for b in per_bin) for per_bin in per_bin_by_model.values()}
    if len(counts) == 1:
        ax.set_xticks(x, [f"{lab}\nn={n:,}" for lab, n in zip(labels, counts.pop(), strict=True)])
        ax.set_xlabel("true angular speed ‖ω̂‖ [deg/s]  (n = evaluated 1 ms steps)")
    else:
        ax.set_xticks(x, labels)
        ax.set_xlabel("true angular speed ‖ω̂‖ [deg/s]  (models scored on different data)")
    ax.set_ylabel("median relative error ‖ω − ω̂‖ / ‖ω̂‖ [-]")
    ax.set_ylim(0, max(top * 1.15, 0.1))
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    ax.set_xlim(-0.6, len(labels) - 0.4)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="model")
    fig.tight_layout()
    return fig


def _axis_boxes(ax: Any, per_bin: Sequence[Mapping[str, Any]]) -> float:
    """Draw one model's per-axis boxes per speed bin on ``ax``; returns the largest |whisker|."""
    width = 0.25
    reach = 0.0
    for i, b in enumerate(per_bin):
        for j, axis in enumerate(AXES):
            stats = b.get("per_axis", {}).get(axis, {}).get("relative_error", {"n": 0})
            if stats["n"] == 0:
                continue
            reach = max(reach, abs(stats["whislo"]), abs(stats["whishi"]))
            ax.bxp(
                [stats],
                positions=[i + (j - 1) * (width + 0.03)],
                widths=width,
                showfliers=False,
                patch_artist=True,
                boxprops={"facecolor": AXIS_COLORS[axis], "alpha": 0.8},
                medianprops={"color": "black"},
            )
    _mark_empty(ax, [per_bin])
    ax.axhline(0.0, color="black", linewidth=0.8, linestyle=":")
    ax.set_xticks(range(len(per_bin)), [f"{b['label']}\nn={b['n_pairs']:,}" for b in per_bin])
    ax.set_xlim(-0.6, len(per_bin) - 0.4)
    ax.grid(axis="y", alpha=0.3)
    return reach


def _box_figure(panels: Mapping[str, Sequence[Mapping[str, Any]]], title: str) -> Figure:
    """One row of per-axis boxes per panel (model), on a shared y range."""
    bins = len(next(iter(panels.values())))
    fig = Figure(figsize=(max(8.5, 1.3 * bins + 1.5), 0.4 + 3.6 * len(panels)))
    axes = fig.subplots(len(panels), 1, sharex=True, sharey=True, squeeze=False)
    reach = 0.0
    for ax, (name, per_bin) in zip(axes[:, 0], panels.items(), strict=True):
        reach = max(reach, _axis_boxes(ax, per_bin))
        ax.set_title(title.format(model=name))
    clipped = False
    if reach > 0:
        span = max(reach, 0.05) * 1.1
        clipped = span > BOX_CLIP
        axes[0, 0].set_ylim(-min(span, BOX_CLIP), min(span, BOX_CLIP))
    ylabel = "signed relative error (ω_i − ω̂_i) / |ω̂_i| [-]"
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel + (f"\n(clipped at ±{BOX_CLIP:g})" if clipped else ""))
    axes[-1, 0].set_xlabel("true angular speed ‖ω̂‖ [deg/s]  (n = evaluated 1 ms steps)")
    handles = [
        Patch(facecolor=AXIS_COLORS[a], alpha=0.8, label=f"{a} ({AXIS_SYMBOLS[a]})") for a in AXES
    ]
    axes[0, 0].legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                      title="axis")  # fmt: skip
    fig.tight_layout()
    return fig


def axis_relative_error_boxes(per_bin: Sequence[Mapping[str, Any]], model_name: str) -> Figure:
    """Box plots of the signed per-axis relative error per speed bin (paper Fig. 5).

    Boxes span the quartiles, whiskers reach the furthest value within 1.5 IQR; outliers are not
    drawn. Reads the box statistics stored by :func:`spikegyro.evaluate.bins.per_bin_metrics`.
    """
    return _box_figure({model_name: per_bin}, "{model}: per-axis relative error per speed bin")


def axis_relative_error_boxes_by_model(
    per_bin_by_model: Mapping[str, Sequence[Mapping[str, Any]]],
) -> Figure:
    """:func:`axis_relative_error_boxes` of several models, one row each, on one y range (the
    comparison of the paper's Fig. 5 across models; all with the same bins)."""
    return _box_figure(per_bin_by_model, "{model}")


def omega_traces(
    t_ms: np.ndarray,
    series: Mapping[str, np.ndarray],
    reference: tuple[np.ndarray, np.ndarray],
    held: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    shade_until_ms: float | None = None,
    title: str = "",
    reference_label: str = "gyro",
) -> Figure:
    """Angular velocity per axis over time: a reference, per-ms series and held estimates.

    Args:
        t_ms: (K,) times of the per-ms series, ms.
        series: model name -> (K, 3) angular velocity, deg/s (drawn as lines in the model's
            color).
        reference: (times ms, (M, 3) deg/s) of the reference, drawn black with its samples.
        held: model name -> (starts ms, ends ms, (n, 3) deg/s): one value held over each
            interval (e.g. one estimate per window), drawn as thick segments.
        shade_until_ms: grey out ``t < shade_until_ms`` (the unscored warm-up).
        reference_label: the reference's name in the legend.
    """
    fig = Figure(figsize=(10.0, 7.0))
    axes = fig.subplots(3, 1, sharex=True)
    ref_t, ref = reference
    for i, (ax, axis) in enumerate(zip(axes, AXES, strict=True)):
        if shade_until_ms is not None:
            ax.axvspan(min(t_ms[0], 0.0) if len(t_ms) else 0.0, shade_until_ms, color="0.92")
        ax.plot(ref_t, ref[:, i], color="black", lw=1.4, marker=".", ms=3, label=reference_label)
        for name, values in series.items():
            ax.plot(t_ms, values[:, i], color=model_color(name), lw=1.0, label=name)
        for name, (starts, ends, values) in (held or {}).items():
            ax.hlines(values[:, i], starts, ends, color=model_color(name), lw=3.0, alpha=0.7,
                      label=name)  # fmt: skip
        ax.set_ylabel(f"{axis} {AXIS_SYMBOLS[axis]}\n[deg/s]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axes[-1].set_xlabel("time since the start [ms]" + (" (grey: warm-up, not scored)"
                                                        if shade_until_ms else ""))  # fmt: skip
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return fig


def offset_curve(
    offsets_ms: np.ndarray, correlations: np.ndarray, best_ms: float | None, applied_ms: float
) -> Figure:
    """Normalised cross-correlation of event-based estimates with the gyro against the clock
    offset added to the gyro's timestamps (ms), with the best and the applied offset marked."""
    fig = Figure(figsize=(7.0, 3.6))
    ax = fig.add_subplot()
    ax.plot(offsets_ms, correlations, color="black", lw=1.2)
    if best_ms is not None:
        ax.axvline(best_ms, color="#D55E00", ls="--", label=f"best fit {best_ms:+.2f} ms")
    ax.axvline(applied_ms, color="#0072B2", ls=":", label=f"applied {applied_ms:+.2f} ms")
    ax.set_xlabel("offset added to the gyro's timestamps [ms]")
    ax.set_ylabel("normalised cross-correlation [-]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
