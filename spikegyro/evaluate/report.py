"""Report writer: one self-contained HTML page (PNG figures embedded as base64) and a Markdown
twin (figures linked as files), built from a list of blocks: paragraphs, tables and figures.

Also the table builders shared by ``evaluate`` and ``report`` and the paper's published numbers,
always labeled as the paper's (its data, Sun360 panoramas through ESIM, is not ours).
"""

from __future__ import annotations

import base64
import html
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spikegyro.events.io import atomic_path
from spikegyro.metrics import AXES, EVAL_START_STEP, MIN_SPEED_DEG_S, WINDOW_METRIC_MS

PAPER_RESULTS: dict[str, dict[str, float]] = {
    "Mean": {"median_relative_error": 1.00, "mean_euclidean_error_deg_s": 226.9},
    "SNN-6": {"median_relative_error": 0.26, "mean_euclidean_error_deg_s": 66.3},
    "ANN-6 (voxel)": {"median_relative_error": 0.22, "mean_euclidean_error_deg_s": 59.0},
    "ResNet-50 (accumulated frames)": {
        "median_relative_error": 0.22,
        "mean_euclidean_error_deg_s": 66.8,
    },
    "ResNet-50 (voxel)": {"median_relative_error": 0.15, "mean_euclidean_error_deg_s": 36.8},
}
"""Gehrig et al. 2020, Table I (test set), by row: median relative error and mean Euclidean
error (their "RMSE"), deg/s."""

PAPER_ROW_OF_MODEL: dict[tuple[str, str], str] = {
    ("snn6", "spikes"): "SNN-6",
    ("ann6", "voxel"): "ANN-6 (voxel)",
    ("resnet50", "frames"): "ResNet-50 (accumulated frames)",
    ("resnet50", "voxel"): "ResNet-50 (voxel)",
}
"""(registry name, input representation) -> the paper's row; other pairs have no paper number."""

_REPRESENTATION_TAGS = {
    "e": "spikes", "spikes": "spikes", "events": "spikes",
    "v": "voxel", "voxel": "voxel", "voxels": "voxel", "voxelgrid": "voxel",
    "a": "frames", "frames": "frames", "accumulatedframes": "frames", "accumulated": "frames",
}  # fmt: skip
_DEFAULT_REPRESENTATION = {"snn6": "spikes", "ann6": "voxel"}


def display_name(payload: dict[str, Any]) -> str:
    """The model's name in tables and legends, from its checkpoint (e.g. ``ResNet-50 (V)``)."""
    model = payload.get("model", "model")
    rep = payload.get("input", {}).get("representation", "")
    tag = {"voxel": "V", "frames": "A", "spikes": "E"}.get(rep, rep)
    if model == "snn6":
        return "SNN-6" if rep == "spikes" else f"SNN-6 ({tag})"
    if model == "ann6":
        return "ANN-6" if rep == "voxel" else f"ANN-6 ({tag})"
    if model == "resnet50":
        return f"ResNet-50 ({tag})"
    return model


def paper_row(result: Mapping[str, Any]) -> str | None:
    """The row of the paper's Table I that a model's results (a ``metrics.json`` model entry)
    compare with, or None.

    Decided by the checkpoint's registry name (``checkpoint_model``) and input representation
    (``input.representation``), or ``method == "mean"`` for the mean predictor; other methods
    (CMax) have none. Only entries written before those keys existed fall back to the display
    name (:func:`paper_row_from_name`).
    """
    arch = result.get("checkpoint_model")
    if arch is not None:
        representation = (result.get("input") or {}).get("representation", "")
        return PAPER_ROW_OF_MODEL.get((arch, representation))
    if "method" in result:
        return "Mean" if result["method"] == "mean" else None
    return paper_row_from_name(str(result.get("name", "")))


def paper_row_from_name(name: str) -> str | None:
    """The paper's row for a display name such as ``ANN-6 (V)``, ``ResNet-50 (voxel)`` or
    ``SNN-6 (official) [run2]``; None when there is none or the name is ambiguous (``ResNet-50``
    without its input). Case, spaces and dashes do not matter; ``(official)`` and a run tag in
    brackets are ignored.
    """
    text = name.split("[", 1)[0].lower()
    tags = {re.sub(r"[^a-z0-9]", "", t) for t in re.findall(r"\(([^)]*)\)", text)} - {"official"}
    base = re.sub(r"[^a-z0-9]", "", re.sub(r"\([^)]*\)", "", text))
    if base == "mean":
        return None if tags else "Mean"
    reps = {_REPRESENTATION_TAGS.get(t) for t in tags}
    if len(reps) > 1 or None in reps:
        return None
    representation = reps.pop() if reps else _DEFAULT_REPRESENTATION.get(base, "")
    return PAPER_ROW_OF_MODEL.get((base, representation))


@dataclass(frozen=True)
class Table:
    """A table of preformatted cells; ``caption`` says what the numbers are and their units."""

    caption: str
    header: Sequence[str]
    rows: Sequence[Sequence[str]]


@dataclass(frozen=True)
class FigureRef:
    """A PNG figure in the report folder; ``file`` is relative to that folder."""

    caption: str
    file: str


Block = str | Table | FigureRef


def fmt(value: Any, digits: int = 3) -> str:
    """A number with ``digits`` decimals, ``-`` for a missing one (None)."""
    if value is None:
        return "-"
    if isinstance(value, int):
        return f"{value:,}"
    return f"{value:.{digits}f}"


def write_report(out_dir: str | os.PathLike, title: str, blocks: Sequence[Block]) -> list[Path]:
    """Write ``out_dir/report.html`` (self-contained) and ``out_dir/report.md``; returns both."""
    out_dir = Path(out_dir)
    paths = []
    for name, text in (
        ("report.html", _html(out_dir, title, blocks)),
        ("report.md", _markdown(title, blocks)),
    ):
        with atomic_path(out_dir / name) as tmp:
            tmp.write_text(text, encoding="utf-8")
        paths.append(out_dir / name)
    return paths


_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #eee; }
caption { caption-side: top; text-align: left; font-weight: 600; padding-bottom: 0.3em; }
figure { margin: 1em 0 2em; } img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; }
"""


def _html(out_dir: Path, title: str, blocks: Sequence[Block]) -> str:
    esc = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
    ]
    for block in blocks:
        if isinstance(block, Table):
            head = "".join(f"<th>{esc(h)}</th>" for h in block.header)
            body = "".join(
                "<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in block.rows
            )
            parts.append(
                f"<table><caption>{esc(block.caption)}</caption>"
                f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
            )
        elif isinstance(block, FigureRef):
            data = base64.b64encode((out_dir / block.file).read_bytes()).decode("ascii")
            parts.append(
                f'<figure><img alt="{esc(block.caption)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{esc(block.caption)}</figcaption></figure>"
            )
        elif block.startswith("## "):
            parts.append(f"<h2>{esc(block[3:])}</h2>")
        else:
            parts.append(f"<p>{esc(block)}</p>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _markdown(title: str, blocks: Sequence[Block]) -> str:
    lines = [f"# {title}", ""]
    for block in blocks:
        if isinstance(block, Table):
            lines += [f"**{block.caption}**", ""]
            lines.append("| " + " | ".join(_md_cell(c) for c in block.header) + " |")
            lines.append("|" + "|".join([":--"] + ["--:"] * (len(block.header) - 1)) + "|")
            for row in block.rows:
                lines.append("| " + " | ".join(_md_cell(c) for c in row) + " |")
        elif isinstance(block, FigureRef):
            lines += [f"![{block.caption}]({block.file})", "", f"*{block.caption}*"]
        else:
            lines.append(block)
        lines.append("")
    return "\n".join(lines)


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|")


PER_MS_LABEL = f"per ms (steps ≥ {EVAL_START_STEP})"
PER_WINDOW_LABEL = f"per {WINDOW_METRIC_MS} ms window (mean prediction vs mean truth)"


def metric_header(window_label: str = PER_WINDOW_LABEL) -> list[str]:
    """Column heads of :func:`metric_cells`: per-ms then per-window metrics."""
    return [
        f"{PER_MS_LABEL}: median rel. error",
        f'{PER_MS_LABEL}: mean Eucl. error (paper "RMSE") [deg/s]',
        f"{PER_MS_LABEL}: RMSE [deg/s]",
        f"{PER_MS_LABEL}: steps",
        f"{window_label}: median rel. error",
        f"{window_label}: mean Eucl. error [deg/s]",
        f"{window_label}: RMSE [deg/s]",
        f"{window_label}: windows",
    ]


def metric_cells(result: Mapping[str, Any]) -> list[str]:
    """The cells under :func:`metric_header` for one model entry: ``metrics`` (from
    :func:`spikegyro.metrics.summary`, or None: all ``-``) and optionally
    ``window_metrics`` (the same keys plus ``n_windows``; ``-`` where missing)."""
    m = result.get("metrics") or {}
    w = result.get("window_metrics") or {}
    return [
        fmt(m.get("median_relative_error")),
        fmt(m.get("mean_euclidean_error_deg_s"), 1),
        fmt(m.get("rmse_deg_s"), 1),
        fmt(m.get("n_pairs")),
        fmt(w.get("median_relative_error")),
        fmt(w.get("mean_euclidean_error_deg_s"), 1),
        fmt(w.get("rmse_deg_s"), 1),
        fmt(w.get("n_windows")),
    ]


def overall_table(models: Mapping[str, Mapping[str, Any]], caption: str) -> Table:
    """One row per model: our per-ms and per-window metrics, then the paper's numbers.

    ``models`` maps display name -> a ``metrics.json`` model entry: ``metrics`` (from
    :func:`spikegyro.metrics.summary`), optionally ``window_metrics`` (from
    :func:`spikegyro.metrics.window_metrics`; ``-`` where missing) and what
    :func:`paper_row` reads. The caption is extended with what the two metric groups mean.
    """
    header = [
        "model",
        *metric_header(),
        "paper row (Table I)",
        "paper: median rel. error",
        'paper: "RMSE" [deg/s]',
    ]
    rows = []
    sub_windows: list[list[int]] = []
    for name, result in models.items():
        w = result.get("window_metrics") or {}
        sub_windows = sub_windows or w.get("sub_windows_ms", [])
        row = paper_row(result)
        paper = PAPER_RESULTS.get(row, {}) if row else {}
        rows.append(
            [
                name,
                *metric_cells(result),
                row or "-",
                fmt(paper.get("median_relative_error"), 2),
                fmt(paper.get("mean_euclidean_error_deg_s"), 1),
            ]
        )
    spans = " and ".join(f"[{a}, {b}) ms" for a, b in sub_windows) or "none"
    caption = (
        f"{caption}. {PER_MS_LABEL}: every millisecond from {EVAL_START_STEP} ms on, ANN "
        f"predictions held over their window. {PER_WINDOW_LABEL}: the {WINDOW_METRIC_MS} ms "
        "windows counted from the window start (as the ANNs') that lie wholly in the evaluated "
        f"steps ({spans}), one error per window between the mean prediction and the mean ground "
        "truth (relative errors leave out windows whose mean true speed is under "
        f"{MIN_SPEED_DEG_S:g} deg/s, as per ms)."
    )
    return Table(caption, header, rows)


def axis_table(models: Mapping[str, Mapping[str, Any]]) -> Table:
    """Per model and axis: absolute errors (deg/s) and the signed relative error's quartiles."""
    header = [
        "model",
        "axis",
        "mean abs. error [deg/s]",
        "RMSE [deg/s]",
        "median abs. rel. error",
        "signed rel. error: q1 / median / q3",
    ]
    rows = []
    for name, m in models.items():
        for axis in AXES:
            a = m["per_axis"][axis]
            box = a["relative_error"]
            quartiles = (
                f"{box['q1']:+.3f} / {box['med']:+.3f} / {box['q3']:+.3f}" if box["n"] else "-"
            )
            rows.append(
                [
                    name,
                    axis,
                    fmt(a["mean_abs_error_deg_s"], 1),
                    fmt(a["rmse_deg_s"], 1),
                    fmt(a["median_abs_relative_error"]),
                    quartiles,
                ]
            )
    return Table(
        "Per-axis errors (steps >= 50; relative errors leave out |true component| < 1 deg/s)",
        header,
        rows,
    )


def bin_table(per_bin_by_model: Mapping[str, Sequence[Mapping[str, Any]]]) -> Table:
    """One row per model, one column per speed bin: median relative error / mean Euclidean
    error (deg/s); then the evaluated steps per bin (one row per distinct data set)."""
    names = list(per_bin_by_model)
    labels = [b["label"] for b in per_bin_by_model[names[0]]]
    rows = []
    for name in names:
        cells = [
            f"{fmt(b.get('median_relative_error'))} / {fmt(b.get('mean_euclidean_error_deg_s'), 1)}"
            if b["n_pairs"]
            else "-"
            for b in per_bin_by_model[name]
        ]
        rows.append([name, *cells])
    counts: dict[tuple[int, ...], list[str]] = {}
    for name in names:
        counts.setdefault(tuple(b["n_pairs"] for b in per_bin_by_model[name]), []).append(name)
    for key, owners in counts.items():
        label = "steps" if len(counts) == 1 else f"steps ({', '.join(owners)})"
        rows.append([label, *(fmt(n) for n in key)])
    return Table(
        "Per true-speed bin [deg/s]: median relative error / mean Euclidean error [deg/s]",
        ["model", *labels],
        rows,
    )
