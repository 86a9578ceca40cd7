"""``spikegyro report``: the paper's Table I over evaluated runs, with training budget and energy.

Reads the ``metrics.json`` of each ``spikegyro evaluate`` output folder and writes into ``OUT``:

- ``report.html`` / ``report.md``: Table I (per model: input, training steps and time, median
  relative error and mean Euclidean error per ms and per 20 ms window, operations and energy per
  estimate), each of our rows followed by the paper's published row for that model, labelled as
  the paper's; the energy table with its sources; the per-speed-bin table and figure (Fig. 4);
- the per-axis table: mean absolute error on tilt, pan and roll, every model side by side;
- the paper's three figure kinds with every model side by side: ``bins.png`` (median relative
  error per speed bin, Fig. 4), ``boxes.png`` (signed relative error per axis and speed bin,
  Fig. 5, one row per model) and ``window.png`` (one test window: ground truth and every model's
  ω over time, Fig. 3; from the runs' ``predictions.npz``, so all runs must have scored the same
  windows);
- ``comparison.json``: the numbers, machine-readable.

Training steps and time come from the checkpoint named in ``metrics.json`` (its ``extra``: step
and elapsed seconds of the run, device when the run named one), "n/a" where it is not readable
(e.g. the paper's official weights, CMax, a moved file). Operations: SynOps from the SNN's spike
statistics, MACs counted on the checkpoint's model (:mod:`spikegyro.evaluate.energy`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.markup import escape
from rich.table import Table as RichTable

from spikegyro.errors import InputError
from spikegyro.evaluate import energy, figures
from spikegyro.evaluate.console import write_json
from spikegyro.evaluate.report import (
    PAPER_RESULTS,
    PER_MS_LABEL,
    PER_WINDOW_LABEL,
    Block,
    FigureRef,
    Table,
    bin_table,
    fmt,
    paper_row,
    write_report,
)
from spikegyro.metrics import AXES, EVAL_START_STEP, WINDOW_METRIC_MS
from spikegyro.models.registry import build_model, read_checkpoint, training_total
from spikegyro.train.data import InputSpec

METRICS_FORMAT = "spikegyro-metrics/1"
NOT_AVAILABLE = "n/a"
PAPER_LABEL = "Gehrig et al. 2020 (paper, their data)"
INPUT_NAMES = {"spikes": "events (1 ms spikes)", "voxel": "voxel grid", "frames": "accum. frames"}


def load_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Read ``run_dir/metrics.json`` written by ``evaluate``."""
    path = Path(run_dir) / "metrics.json"
    if not path.exists():
        raise InputError(f"{run_dir}: no metrics.json; run `spikegyro evaluate --out {run_dir}`.")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}).") from None
    if data.get("format") != METRICS_FORMAT:
        raise InputError(f"{path}: not a spikegyro metrics file (format {data.get('format')}).")
    return data


def _checkpoint(entry: dict[str, Any]) -> dict[str, Any] | None:
    """The checkpoint an entry was evaluated from, or what ``evaluate`` recorded of it when the
    file has gone (:func:`checkpoint_meta`); None for CMax, the mean and older moved files."""
    if entry.get("method") != "checkpoint":
        return None
    try:
        return read_checkpoint(entry["source"])
    except InputError:
        return entry.get("checkpoint_meta")


def checkpoint_meta(payload: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint without its weights: what :func:`training_info` and :func:`operations` read
    (model, constructor arguments, input, steps, time, device, precision). ``evaluate`` keeps it
    in ``metrics.json``, so a report made after the checkpoint has gone (a GPU machine's run)
    still shows the training budget and the operations."""
    extra = payload.get("extra", {})
    kept = {key: extra[key] for key in ("step", "elapsed_s", "before") if key in extra}
    config = extra.get("config") or {}
    kept["config"] = {key: config[key] for key in ("device", "amp") if key in config}
    return {
        "model": payload.get("model"),
        "model_kwargs": payload.get("model_kwargs") or {},
        "input": payload.get("input"),
        "extra": kept,
    }


def training_info(payload: dict[str, Any] | None) -> dict[str, Any]:
    """Steps, wall-clock minutes, device and precision of the training behind a checkpoint (None:
    unknown).

    ``steps`` and ``minutes`` add the checkpoint's own run and the runs it was continued from
    with ``--init`` (their totals are in ``extra["before"]``); ``device`` is the one the run's
    configuration named, None for ``auto``; ``amp`` its mixed precision ("off" before it existed).
    """
    extra = (payload or {}).get("extra", {})
    config = extra.get("config") or {}
    device = config.get("device")
    total = training_total(payload or {})
    return {
        "steps": None if extra.get("step") is None else total["steps"],
        "minutes": None if extra.get("elapsed_s") is None else total["elapsed_s"] / 60.0,
        "device": None if device in (None, "auto") else device,
        "amp": config.get("amp", "off"),
    }


def _network_size(spec: InputSpec) -> tuple[int, int]:
    """(width, height) in px of the model's input: the sensor scaled as the events are."""
    width, height = (max(1, round(side * spec.scale)) for side in spec.sensor)
    return width, height


def operations(entry: dict[str, Any], payload: dict[str, Any] | None) -> dict[str, Any] | None:
    """Operations per estimate and per second of a model entry, or None when not countable."""
    spikes = entry.get("spikes") or {}
    if spikes.get("synops_per_s") is not None:
        return energy.snn_operations(spikes)
    if payload is None or payload.get("input", {}).get("output") != "window_mean":
        return None
    model = build_model(payload["model"], **payload["model_kwargs"])  # MACs need no weights
    spec = InputSpec.from_dict(payload["input"])
    first = next(m for m in model.modules() if isinstance(m, torch.nn.Conv2d))
    width, height = _network_size(spec)
    macs = energy.count_macs(model, torch.zeros(1, first.in_channels, height, width))
    return energy.ann_operations(macs, spec.target_ms)


def _input_text(entry: dict[str, Any]) -> str:
    """Input representation and resolution (px) the model saw, e.g. ``voxel grid, 120x90``."""
    if entry.get("method") == "mean":
        return "-"
    if "input" not in entry:  # contrast maximization: raw events
        return "events"
    spec = InputSpec.from_dict(entry["input"])
    width, height = _network_size(spec)
    return f"{INPUT_NAMES[spec.representation]}, {width}x{height}"


def _figure_45nm(ops: dict[str, Any]) -> str:
    """The 45 nm operation that one of ``ops`` costs: a float add per SynOp, a MAC per MAC."""
    return "add_fp32_45nm" if ops["kind"] == "SynOps" else "mac_fp32_45nm"


def _row_energy(ops: dict[str, Any] | None) -> tuple[str, str, str]:
    if ops is None:
        return "-", "-", "-"
    joules = energy.energy(ops)
    figure = _figure_45nm(ops)
    return (
        f"{ops['per_estimate']:.3g} {ops['kind']}",
        f"{joules[f'{figure}_uj_per_estimate']:.3g}",
        f"{joules[f'{figure}_mw']:.3g}",
    )


TABLE_ONE_HEADER = (
    "model",
    "input",
    "training steps",
    "training time [min] (device)",
    f"{PER_MS_LABEL}: median rel. error",
    f'{PER_MS_LABEL}: mean Eucl. error (paper "RMSE") [deg/s]',
    f"{PER_WINDOW_LABEL}: median rel. error",
    f"{PER_WINDOW_LABEL}: mean Eucl. error [deg/s]",
    "operations per estimate",
    "energy per estimate, 45 nm [µJ]",
    "power, 45 nm [mW]",
)


def table_one(models: dict[str, dict[str, Any]]) -> Table:
    """The paper's Table I with our numbers: one row per model (its ``info`` from
    :func:`compare_runs`), each followed by the paper's row for that model, labelled as such."""
    rows = []
    for name, entry in models.items():
        m, w = entry["metrics"], entry.get("window_metrics") or {}
        info, ops = entry["info"], entry["operations"]
        minutes = info["minutes"]
        time = NOT_AVAILABLE if minutes is None else f"{minutes:.1f}"
        if minutes is not None:
            amp = "" if info["amp"] == "off" else f", {info['amp']}"
            time += f" ({info['device'] or NOT_AVAILABLE}{amp})"
        rows.append(
            [
                name,
                _input_text(entry),
                NOT_AVAILABLE if info["steps"] is None else fmt(int(info["steps"])),
                time,
                fmt(m["median_relative_error"]),
                fmt(m["mean_euclidean_error_deg_s"], 1),
                fmt(w.get("median_relative_error")),
                fmt(w.get("mean_euclidean_error_deg_s"), 1),
                *_row_energy(ops),
            ]
        )
        row = paper_row(entry)
        if row is not None:
            paper = PAPER_RESULTS[row]
            rows.append(
                [
                    f"{PAPER_LABEL}: {row}",
                    "-", "-", "-",
                    fmt(paper["median_relative_error"], 2),
                    fmt(paper["mean_euclidean_error_deg_s"], 1),
                    "-", "-", "-", "-", "-",
                ]
            )  # fmt: skip
    return Table(
        "Table I (Gehrig et al. 2020) on our data. Ours: median relative error and mean Euclidean "
        f'error (the paper\'s "RMSE") {PER_MS_LABEL} and {PER_WINDOW_LABEL}; training steps and '
        "wall-clock time of the run (from the checkpoint; n/a where not recorded). Rows labelled "
        f'"{PAPER_LABEL}" are the published numbers, measured on the paper\'s own data (Sun360 '
        "through ESIM), one figure per model, shown under the per-ms columns. Operations: "
        "SynOps (SNN, event-driven, per 1 ms estimate) or MACs (ANNs, one dense forward pass per "
        "20 ms estimate); energy at 45 nm: SynOps x 0.9 pJ (float add), MACs x 4.6 pJ (float "
        "MAC), arithmetic only (see the energy table)",
        TABLE_ONE_HEADER,
        rows,
    )


def energy_table(models: dict[str, dict[str, Any]]) -> Table:
    """Operations and energy per estimate and per second, on each platform that fits."""
    rows = []
    for name, entry in models.items():
        ops = entry["operations"]
        if ops is None:
            continue
        joules = energy.energy(ops)
        figure = _figure_45nm(ops)
        loihi = ops["kind"] == "SynOps"
        dense = ops.get("dense_macs_per_estimate")
        rows.append(
            [
                name,
                ops["kind"],
                f"{ops['estimate_period_ms']:g} ms",
                f"{ops['per_estimate']:.3g}",
                f"{ops['per_second']:.3g}",
                f"{joules[f'{figure}_uj_per_estimate']:.3g}",
                f"{joules[f'{figure}_mw']:.3g}",
                f"{joules['synop_loihi_uj_per_estimate']:.3g}" if loihi else "-",
                f"{joules['synop_loihi_mw']:.3g}" if loihi else "-",
                "-" if dense is None else f"{dense:.3g}",
            ]
        )
    figures_text = "; ".join(
        f"{f.operation} on {f.platform}: {f.picojoules:g} pJ ({f.source})"
        for f in energy.ENERGY_FIGURES.values()
    )
    return Table(
        "Operations and energy per estimate. SNN-6: SynOps from its measured spikes (one "
        "accumulate per spike and outgoing synapse), one estimate per 1 ms; ANNs: MACs of one "
        f"forward pass, one estimate per target window. Per-operation energies: {figures_text}. "
        "45 nm figures are arithmetic only (no memory traffic, which dominates in practice); "
        "Loihi's is the chip's minimum per synaptic op, without neuron updates: lower bounds",
        [
            "model",
            "operation",
            "estimate every",
            "ops per estimate",
            "ops per second",
            "45 nm: µJ per estimate",
            "45 nm: mW",
            "Loihi: µJ per estimate",
            "Loihi: mW",
            "SNN run densely: MACs per estimate",
        ],
        rows,
    )


def axis_mae_table(models: dict[str, dict[str, Any]]) -> Table:
    """One row per model: mean absolute error (deg/s) on tilt, pan and roll side by side, then
    the mean Euclidean error for scale; "-" where a run has no per-axis metrics."""
    rows = []
    for name, entry in models.items():
        m = entry["metrics"]
        per_axis = m.get("per_axis") or {}
        rows.append(
            [
                name,
                *(fmt((per_axis.get(axis) or {}).get("mean_abs_error_deg_s"), 1) for axis in AXES),
                fmt(m.get("mean_euclidean_error_deg_s"), 1),
            ]
        )
    return Table(
        f"Per-axis mean absolute error [deg/s], {PER_MS_LABEL}: tilt (x), pan (y), roll (z, about "
        "the optical axis), every model side by side; the mean Euclidean error for scale",
        ["model", *(f"{axis} [deg/s]" for axis in AXES), "mean Eucl. error [deg/s]"],
        rows,
    )


def compare_runs(
    run_dirs: list[str | os.PathLike], out_dir: str | os.PathLike, window: int | None = None
) -> dict[str, dict[str, Any]]:
    """Table I, energy and the paper's figures over several ``evaluate`` outputs.

    The mean predictor is taken from the first run; ``window``: the test window of the
    qualitative figure (default: the one of median speed). Returns {model name: its
    metrics.json entry plus ``info`` (training) and ``operations``}.
    """
    if not run_dirs:
        raise InputError("report: give at least one RUN_DIR written by `spikegyro evaluate`.")
    out_dir = Path(out_dir)
    runs = [load_run(r) for r in run_dirs]
    edges = runs[0]["bins"]["edges_deg_s"]
    models: dict[str, dict[str, Any]] = {}
    notes = []
    for run_dir, run in zip(run_dirs, runs, strict=True):
        if run["bins"]["edges_deg_s"] != edges:
            raise InputError(f"{run_dir}: its speed bins differ from {run_dirs[0]}'s.")
        key = run["model"]["name"]
        if key in models:
            key = f"{key} [{Path(run_dir).name}]"
        payload = _checkpoint(run["model"])
        models[key] = {
            **run["model"],
            "info": training_info(payload),
            "operations": operations(run["model"], payload),
        }
        notes.append(
            f"{key}: {run_dir} ({run['data']['dir']} / {run['data']['split']}, "
            f"{run['data']['windows']:,} windows)"
        )
    models["Mean"] = {**runs[0]["mean"], "info": training_info(None), "operations": None}
    if len({(r["data"]["dir"], r["data"]["split"], r["data"]["windows"]) for r in runs}) > 1:
        notes.append("Warning: the runs were scored on different data; compare with care.")
    out_dir.mkdir(parents=True, exist_ok=True)
    per_bin = {k: m["per_bin"] for k, m in models.items()}
    blocks: list[Block] = [
        *notes,
        table_one(models),
        axis_mae_table(models),
        energy_table(models),
        *comparison_figures(run_dirs, list(models)[: len(runs)], per_bin, out_dir, window),
        bin_table(per_bin),
    ]
    write_report(out_dir, "spikegyro comparison (paper Table I)", blocks)
    summary = {
        k: {
            "metrics": m["metrics"],
            "window_metrics": m.get("window_metrics"),
            "paper_row": paper_row(m),
            "paper": PAPER_RESULTS.get(paper_row(m) or ""),
            "training": m["info"],
            "operations": m["operations"],
            "energy": None if m["operations"] is None else energy.energy(m["operations"]),
            "per_bin": m["per_bin"],
        }
        for k, m in models.items()
    }
    write_json(out_dir / "comparison.json", summary)
    return models


def comparison_figures(
    run_dirs: list[str | os.PathLike],
    names: list[str],
    per_bin: dict[str, Any],
    out_dir: Path,
    window: int | None,
) -> list[Block]:
    """The paper's three figure kinds with every model side by side, written to ``out_dir``;
    their report entries (a note instead of the window figure when it cannot be drawn)."""
    figures.save_figure(figures.median_relative_error_per_bin(per_bin), out_dir / "bins.png")
    learned = {name: bins for name, bins in per_bin.items() if name != "Mean"}
    figures.save_figure(figures.axis_relative_error_boxes_by_model(learned), out_dir / "boxes.png")
    blocks: list[Block] = [
        FigureRef("Median relative error per true-speed bin, all models (paper Fig. 4).",
                  "bins.png"),
        FigureRef("Signed relative error per axis and true-speed bin, one row per model (paper "
                  "Fig. 5); boxes: quartiles, whiskers: 1.5 IQR.", "boxes.png"),
    ]  # fmt: skip
    try:
        fig, caption = window_figure(run_dirs, names, window)
    except InputError as exc:
        if window is not None:
            raise
        return [*blocks, f"No window figure: {exc}"]
    figures.save_figure(fig, out_dir / "window.png")
    return [*blocks, FigureRef(caption, "window.png")]


def _predictions(run_dir: str | os.PathLike) -> dict[str, np.ndarray]:
    path = Path(run_dir) / "predictions.npz"
    if not path.exists():
        raise InputError(f"{path}: missing (written by `spikegyro evaluate`).")
    with np.load(path) as data:
        return {key: data[key] for key in ("pred", "gt", "mean_omega", "sources", "t_start_us")}


def window_figure(
    run_dirs: list[str | os.PathLike], names: list[str], window: int | None
) -> tuple[Any, str]:
    """Ground truth and every model's ω over one test window (``window``: its index; None: the
    window of median true speed over the scored steps), and the figure's caption. InputError
    when the runs scored different windows or the index is out of range."""
    runs = [_predictions(r) for r in run_dirs]
    first = runs[0]
    for run_dir, run in zip(run_dirs[1:], runs[1:], strict=True):
        same = np.array_equal(run["sources"], first["sources"]) and np.array_equal(
            run["t_start_us"], first["t_start_us"]
        )
        if not same:
            raise InputError(f"{run_dir}: scored other windows than {run_dirs[0]}.")
    gt = np.degrees(first["gt"])
    start = EVAL_START_STEP
    if window is None:
        speed = np.linalg.norm(gt[:, start:], axis=-1).mean(axis=1)
        window = int(np.argsort(speed, kind="stable")[len(speed) // 2])
    if not 0 <= window < len(gt):
        raise InputError(f"--window {window}: the runs scored windows 0..{len(gt) - 1}.")
    series = {name: np.degrees(run["pred"][window]) for name, run in zip(names, runs, strict=True)}
    series["Mean"] = np.broadcast_to(np.degrees(first["mean_omega"]), gt[window].shape)
    t_ms = np.arange(1, gt.shape[1] + 1, dtype=np.float64)
    source = Path(str(first["sources"][window])).name
    title = f"window {window}: {source}, from {first['t_start_us'][window] / 1e3:g} ms"
    fig = figures.omega_traces(t_ms, series, (t_ms, gt[window]), shade_until_ms=start,
                               title=title, reference_label="ground truth")  # fmt: skip
    caption = (
        f"One test window, all models on the same events (paper Fig. 3): {title}; angular "
        "velocity per axis at the end of each 1 ms bin, the ANNs' window means held over their "
        "window; grey: the first 50 ms, not scored."
    )
    return fig, caption


CONSOLE_COLUMNS = {
    "model": 0,
    "steps": 2,
    "med. rel. (ms)": 4,
    "mean Eucl. (ms)": 5,
    f"med. rel. ({WINDOW_METRIC_MS} ms)": 6,
    f"mean Eucl. ({WINDOW_METRIC_MS} ms)": 7,
    "µJ/est. (45 nm)": 9,
}


def console_summary(table: Table) -> RichTable:
    """The headline columns of :func:`table_one` for an 80-column terminal (report.md has all)."""
    out = RichTable(title="Table I (errors in deg/s; paper rows: their data)")
    for i, head in enumerate(CONSOLE_COLUMNS):
        out.add_column(escape(head), justify="left" if i == 0 else "right")
    for row in table.rows:
        cells = [row[i] for i in CONSOLE_COLUMNS.values()]
        if cells[0].startswith(PAPER_LABEL):  # the paper's row for the model above
            cells[0] = "  paper"
        out.add_row(*(escape(c) for c in cells))
    return out
