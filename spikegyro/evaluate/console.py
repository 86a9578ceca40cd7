"""Terminal output and JSON files shared by the evaluation commands (simulated and real data)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table as RichTable

from spikegyro.evaluate.kinds import kind_table
from spikegyro.evaluate.report import PER_MS_LABEL, PER_WINDOW_LABEL, Table, fmt
from spikegyro.events.io import atomic_path
from spikegyro.metrics import WINDOW_METRIC_MS


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as indented JSON atomically (NaN is refused: missing values are None)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")


def console_table(title: str, table: Table) -> RichTable:
    """``table`` for the terminal, with the long per-ms / per-window labels shortened."""
    out = RichTable(title=escape(title))
    short_window = f"per {WINDOW_METRIC_MS} ms win."
    for i, head in enumerate(table.header):
        head = head.replace(PER_MS_LABEL, "per ms").replace(PER_WINDOW_LABEL, short_window)
        out.add_column(escape(head), justify="left" if i == 0 else "right", no_wrap=i == 0)
    for row in table.rows:
        out.add_row(*(escape(c) for c in row))
    return out


def print_summary(
    console: Console,
    title: str,
    entries: Sequence[dict[str, Any]],
    warnings: Sequence[str] = (),
    window_label: str = f"{WINDOW_METRIC_MS} ms",
    start_ms: int = 50,
) -> None:
    """The headline metrics of each model entry (``name``, ``metrics``, ``window_metrics``) as
    one terminal table, their metrics per scene kind where known (``per_scene_kind``), then the
    warnings. The full tables are in report.md/html."""
    table = RichTable(title=escape(title))
    columns = ("model", "median rel. err.", "mean Eucl. err.", "RMSE")
    columns += (f"{window_label}: median rel.",)
    for col in columns:
        table.add_column(escape(col), justify="left" if col == "model" else "right")
    for entry in entries:
        m, w = entry.get("metrics") or {}, entry.get("window_metrics") or {}
        table.add_row(
            escape(entry["name"]),
            fmt(m.get("median_relative_error")),
            f"{fmt(m.get('mean_euclidean_error_deg_s'), 1)} deg/s",
            f"{fmt(m.get('rmse_deg_s'), 1)} deg/s",
            fmt(w.get("median_relative_error")),
        )
    console.print(table)
    if (kinds := kind_table(entries)) is not None:
        console.print(console_table(kinds.caption, kinds))
    console.print(f'per ms over steps >= {start_ms}; mean Eucl. err. is the paper\'s "RMSE"')
    for w in warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
