"""Validation error against wall time and against steps of training runs, one curve per run.

Reads each run directory's ``log.csv`` (``spikegyro train``) and plots ``val_mean_err_deg``
against ``elapsed_s``; used for the side-by-side fine-tuning of SNN-6 with the dense path and
the event-driven engine (BENCHMARKS.md):

    spikegyro train --init PRETRAINED --compute dense --out runs/ft-dense ...
    spikegyro train --init PRETRAINED --compute sparse --out runs/ft-sparse ...
    .venv/bin/python bench/finetune_curves.py runs/ft-dense runs/ft-sparse --out curves.png
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def validation_curve(run: Path) -> tuple[list[float], list[float], list[int]]:
    """(elapsed minutes, mean error deg/s, step) of the rows of ``run/log.csv`` with validation."""
    minutes, errors, steps = [], [], []
    with open(run / "log.csv") as f:
        for row in csv.DictReader(f):
            if row.get("val_mean_err_deg"):
                minutes.append(float(row["elapsed_s"]) / 60.0)
                errors.append(float(row["val_mean_err_deg"]))
                steps.append(int(row["step"]))
    return minutes, errors, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path("finetune_curves.png"))
    parser.add_argument("--title", default="SNN-6 fine-tuning on the CPU")
    args = parser.parse_args()
    fig, (ax, by_step) = plt.subplots(1, 2, figsize=(11.0, 4.0), sharey=True)
    for run in args.runs:
        minutes, errors, steps = validation_curve(run)
        ax.plot(minutes, errors, marker="o", ms=3, label=f"{run.name} ({steps[-1]} steps)")
        by_step.plot(steps, errors, marker="o", ms=3, label=run.name)
        print(f"{run.name}: " + ", ".join(
            f"{s} steps {m:.1f} min {e:.1f} deg/s" for m, e, s in zip(minutes, errors, steps,
                                                                      strict=True)))  # fmt: skip
    ax.set_xlabel("wall time (min)")
    ax.set_ylabel("validation mean error (deg/s)")
    by_step.set_xlabel("training step (batch of 8)")
    for axes in (ax, by_step):
        axes.grid(alpha=0.3)
        axes.legend()
    fig.suptitle(args.title)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
