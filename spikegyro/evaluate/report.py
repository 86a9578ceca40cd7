"""Report writer: one self-contained HTML page (PNG figures embedded as base64) and a Markdown
twin (figures linked as files), built from a list of blocks: paragraphs, tables and figures.

Also the table builders shared by ``evaluate`` and ``report`` and the paper's published numbers,
always labeled as the paper's (its data, Sun360 panoramas through ESIM, is not ours).
"""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spikegyro.evaluate.metrics import AXES
from spikegyro.events.io import atomic_path

PAPER_RESULTS: dict[str, dict[str, float]] = {
    "Mean": {"median_relative_error": 1.00, "mean_euclidean_error_deg_s": 226.9},
    "SNN-6": {"median_relative_error": 0.26, "mean_euclidean_error_deg_s": 66.3},
    "ANN-6": {"median_relative_error": 0.22, "mean_euclidean_error_deg_s": 59.0},
    "ResNet-50 (A)": {"median_relative_error": 0.22, "mean_euclidean_error_deg_s": 66.8},
    "ResNet-50 (V)": {"median_relative_error": 0.15, "mean_euclidean_error_deg_s": 36.8},
}
"""Gehrig et al. 2020, Table I (test set): median relative error and mean Euclidean error
(their "RMSE"), deg/s. ANN-6 and ResNet-50 (V) take voxel grids, ResNet-50 (A) accumulated
frames."""


def paper_result(name: str) -> dict[str, float] | None:
    """The paper's numbers for model ``name``; the official SNN-6 checkpoint maps to SNN-6 and a
    run tag (``SNN-6 [run2]``) is ignored."""
    base = name.split(" [", 1)[0]
    return PAPER_RESULTS.get(base) or PAPER_RESULTS.get(base.removesuffix(" (official)"))


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


def overall_table(models: Mapping[str, Mapping[str, Any]], caption: str) -> Table:
    """One row per model: our overall metrics, then the paper's two numbers where it has them.

    ``models`` maps display name -> the dict of :func:`spikegyro.evaluate.metrics.summary`.
    """
    header = [
        "model",
        "median rel. error",
        'mean Eucl. error (paper "RMSE") [deg/s]',
        "RMSE [deg/s]",
        "steps",
        "paper: median rel. error",
        'paper: "RMSE" [deg/s]',
    ]
    rows = []
    for name, m in models.items():
        paper = paper_result(name) or {}
        rows.append(
            [
                name,
                fmt(m["median_relative_error"]),
                fmt(m["mean_euclidean_error_deg_s"], 1),
                fmt(m["rmse_deg_s"], 1),
                fmt(m["n_pairs"]),
                fmt(paper.get("median_relative_error"), 2),
                fmt(paper.get("mean_euclidean_error_deg_s"), 1),
            ]
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
