"""``spikegyro demo``: the whole pipeline end to end on the bundled scenes, on a CPU.

Simulates a small dataset, trains SNN-6 with the ``cpu`` preset under a time budget, evaluates
it beside the mean predictor on the test split, and prints a summary. Everything goes under one
output folder:

- ``data/``: the simulated dataset (kept: a second run reuses it),
- ``run/``: the training run (config.json, log.csv, loss.png, best.pt, last.pt),
- ``evaluation/``: metrics.json, figures, report.html, report.md,
- ``evaluation-pretrained/``: the shipped pretrained SNN-6 scored on the same test split,
- ``summary.json``: the headline numbers and the time each stage took (timings exclude the
  extra evaluation of the pretrained model).
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from spikegyro.evaluate.commands import run_evaluation
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import PRETRAINED_SNN6
from spikegyro.sim.commands import simulate_with_progress
from spikegyro.sim.dataset import SimConfig
from spikegyro.train.loop import train
from spikegyro.train.presets import resolve_config

TARGET_MINUTES = 15.0
TARGET_MEDIAN_REL = 0.5


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo; the defaults keep it within ~15 minutes on a 2-core CPU.

    Attributes:
        out: output folder.
        sequences: simulated 500 ms sequences over all splits.
        val_fraction, test_fraction: share of sequences in the validation and test splits.
        train_minutes: wall-time budget of training, minutes.
        seed: seeds the dataset and the training run.
        workers: simulator processes.
    """

    out: Path = Path("demo-output")
    sequences: int = 160
    val_fraction: float = 0.08
    test_fraction: float = 0.12
    train_minutes: float = 10.0
    seed: int = 0
    workers: int = 2


def run_demo(config: DemoConfig, console: Console | None = None) -> dict[str, Any]:
    """Run simulate → train → evaluate and return (and write) the summary."""
    console = console or Console()
    out = Path(config.out)
    data_dir, run_dir, eval_dir = out / "data", out / "run", out / "evaluation"
    clock = time.perf_counter()
    timings: dict[str, float] = {}

    console.rule("1/3  simulate a dataset from the bundled scenes")
    sim_config = SimConfig(val_fraction=config.val_fraction, test_fraction=config.test_fraction)
    simulate_with_progress(
        data_dir,
        config.sequences,
        config.seed,
        sim_config,
        workers=config.workers,
        console=console,
    )
    timings["simulate_s"] = time.perf_counter() - clock

    console.rule("2/3  train SNN-6 (preset 'cpu')")
    if run_dir.exists():
        shutil.rmtree(run_dir)  # a fresh run each time; the dataset above is reused
    train_config = resolve_config(
        "cpu",
        {
            "data": str(data_dir),
            "out": str(run_dir),
            "max_minutes": config.train_minutes,
            "seed": config.seed,
        },
    )
    result = train(train_config)
    timings["train_s"] = time.perf_counter() - clock - timings["simulate_s"]

    console.rule("3/3  evaluate on the test split")
    evaluation = run_evaluation(data_dir, run_dir / "best.pt", "test", eval_dir, console=console)
    timings["evaluate_s"] = time.perf_counter() - clock - timings["simulate_s"] - timings["train_s"]
    timings["total_s"] = time.perf_counter() - clock
    pretrained = None
    if PRETRAINED_SNN6.exists():
        console.rule("extra: the shipped pretrained SNN-6 on the same test split")
        pretrained = run_evaluation(
            data_dir, PRETRAINED_SNN6, "test", out / "evaluation-pretrained", console=console
        )["model"]["metrics"]

    summary = {
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(config).items()},
        "train_steps": result.steps,
        "timings": timings,
        "snn": evaluation["model"]["metrics"],
        "mean_predictor": evaluation["mean"]["metrics"],
        "pretrained_snn": pretrained,
        "targets": {
            "minutes": TARGET_MINUTES,
            "median_relative_error": TARGET_MEDIAN_REL,
        },
    }
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    _print_summary(console, summary, eval_dir)
    return summary


def _print_summary(console: Console, summary: dict[str, Any], eval_dir: Path) -> None:
    table = Table(title="spikegyro demo: test split, steps 50-99 of each 100 ms window")
    table.add_column("model")
    table.add_column("median relative error", justify="right")
    table.add_column("mean Euclidean error", justify="right")
    table.add_column("RMSE", justify="right")
    rows = [("SNN-6 (trained by this demo)", summary["snn"])]
    if summary["pretrained_snn"] is not None:
        rows.append(("SNN-6 (shipped pretrained)", summary["pretrained_snn"]))
    for name, m in (
        *rows,
        ("mean predictor", summary["mean_predictor"]),
    ):
        table.add_row(
            name,
            f"{m['median_relative_error']:.3f}",
            f"{m['mean_euclidean_error_deg_s']:.1f} deg/s",
            f"{m['rmse_deg_s']:.1f} deg/s",
        )
    console.print(table)
    t = summary["timings"]
    minutes = t["total_s"] / 60
    rel = summary["snn"]["median_relative_error"]
    console.print(
        f"time: simulate {t['simulate_s']:.0f} s, train {t['train_s']:.0f} s "
        f"({summary['train_steps']} steps), evaluate {t['evaluate_s']:.0f} s; "
        f"total {minutes:.1f} min (target <= {TARGET_MINUTES:.0f})"
    )
    verdict = "met" if rel <= TARGET_MEDIAN_REL else "missed"
    console.print(
        f"SNN median relative error {rel:.3f}: target <= {TARGET_MEDIAN_REL} {verdict}. "
        f"Report: {eval_dir / 'report.html'}"
    )
