"""Figures: one fixed color per model across figures, empty bins drawn without failing."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import to_hex

from spikegyro.evaluate import bins, figures


def _per_bin(scale: float) -> list[dict]:
    # Windows at 50, 150 and 250 deg/s: bins from 300 deg/s up stay empty.
    directions = np.array([[1.0, 0, 0], [0.6, 0.8, 0], [0, 0.6, -0.8]])
    gt = np.radians(directions * np.array([[50], [150], [250]]))[:, None].repeat(60, axis=1)
    return bins.per_bin_metrics(gt * (1 + scale) + np.radians(3), gt)


def _legend_colors(fig) -> dict[str, str]:
    legend = fig.axes[0].get_legend()
    handles = legend.legend_handles
    return {
        t.get_text(): to_hex(h.get_facecolor(), keep_alpha=False)
        for t, h in zip(legend.get_texts(), handles, strict=True)
    }


def test_each_model_keeps_its_color_whatever_the_order():
    runs = {"Mean": _per_bin(1.0), "SNN-6": _per_bin(0.2), "my net": _per_bin(0.1)}
    a = _legend_colors(figures.median_relative_error_per_bin(runs))
    b = _legend_colors(figures.median_relative_error_per_bin(dict(reversed(runs.items()))))
    assert a == b
    assert a["SNN-6"] == figures.MODEL_COLORS["SNN-6"].lower()
    assert a["Mean"] == figures.MODEL_COLORS["Mean"].lower()
    assert len(set(a.values())) == 3


def test_box_figure_uses_axis_colors_and_survives_empty_bins():
    fig = figures.axis_relative_error_boxes(_per_bin(0.2), "SNN-6")
    colors = _legend_colors(fig)
    assert colors == {
        f"{axis} ({figures.AXIS_SYMBOLS[axis]})": figures.AXIS_COLORS[axis].lower()
        for axis in ("tilt", "pan", "roll")
    }
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert texts.count("no data") == 3  # bins from 300 deg/s up


def test_the_box_comparison_has_a_row_per_model_on_one_scale():
    runs = {"SNN-6": _per_bin(0.2), "ANN-6": _per_bin(0.9)}
    fig = figures.axis_relative_error_boxes_by_model(runs)
    assert [ax.get_title() for ax in fig.axes] == ["SNN-6", "ANN-6"]
    assert fig.axes[0].get_ylim() == fig.axes[1].get_ylim()
    boxes = [b["per_axis"][a]["relative_error"] for b in runs["ANN-6"] if b["n_pairs"]
             for a in ("tilt", "pan", "roll")]  # fmt: skip
    whiskers = [abs(box[w]) for box in boxes if box["n"] for w in ("whislo", "whishi")]
    assert fig.axes[0].get_ylim()[1] >= max(whiskers)  # the wider model sets the shared scale
