"""Validation error against wall time and against steps of training runs, one curve per run.

Reads each run's ``log.csv`` (``spikegyro train``; a run directory or the CSV itself) and plots
a validation column (``--metric``, default ``val_mean_err_deg``) against ``elapsed_s`` and
against the step; used for the side-by-side fine-tuning of SNN-6 with the dense path and the
event-driven engine, and for Table I's CPU runs (BENCHMARKS.md):

    spikegyro train --init PRETRAINED --compute dense --out runs/ft-dense ...
    spikegyro train --init PRETRAINED --compute sparse --out runs/ft-sparse ...
    .venv/bin/python bench/finetune_curves.py runs/ft-dense runs/ft-sparse --out curves.png
    .venv/bin/python bench/finetune_curves.py RUN-A RUN-V --metric val_median_rel \
        --title "Table I on a 2-core CPU" --out table1_curves.png

A validation row without its own ``elapsed_s`` (one logged between log rows) is placed on the
time axis at the elapsed time of the next row that has one.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def validation_curve(run: Path, metric: str) -> tuple[list[float], list[float], list[int]]:
    """(elapsed minutes, ``metric``, step) of the rows of ``run``'s log with validation."""
    log = run / "log.csv" if run.is_dir() else run
    minutes: list[float] = []
    values: list[float] = []
    steps: list[int] = []
    with open(log) as f:
        for row in csv.DictReader(f):
            if row.get(metric):
                values.append(float(row[metric]))
                steps.append(int(row["step"]))
            if row.get("elapsed_s"):
                minutes += [float(row["elapsed_s"]) / 60.0] * (len(values) - len(minutes))
    return minutes, values[: len(minutes)], steps[: len(minutes)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path("finetune_curves.png"))
    parser.add_argument("--title", default="SNN-6 fine-tuning on the CPU")
    parser.add_argument("--metric", default="val_mean_err_deg", help="A validation column.")
    parser.add_argument("--batch", default="8", help="The runs' batch, for the step axis.")
    args = parser.parse_args()
    fig, (ax, by_step) = plt.subplots(1, 2, figsize=(11.0, 4.0), sharey=True)
    for run in args.runs:
        minutes, errors, steps = validation_curve(run, args.metric)
        name = run.name if run.is_dir() else run.parent.name
        ax.plot(minutes, errors, marker="o", ms=3, label=f"{name} ({steps[-1]} steps)")
        by_step.plot(steps, errors, marker="o", ms=3, label=name)
        print(f"{name}: " + ", ".join(
            f"{s} steps {m:.1f} min {e:.3g}" for m, e, s in zip(minutes, errors, steps,
                                                                strict=True)))  # fmt: skip
    ax.set_xlabel("wall time (min)")
    ax.set_ylabel(args.metric)
    by_step.set_xlabel(f"training step (batch of {args.batch})")
    for axes in (ax, by_step):
        axes.grid(alpha=0.3)
        axes.legend()
    fig.suptitle(args.title)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
