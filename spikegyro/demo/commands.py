"""``spikegyro demo``: options in, :func:`spikegyro.demo.run_demo` out."""

from __future__ import annotations

from pathlib import Path

import typer

from spikegyro.checks import check_output_dir
from spikegyro.demo.pipeline import DemoConfig, run_demo


def demo_command(
    out: Path = typer.Option(DemoConfig.out, "--out", help="Output folder."),
    test_sequences: int = typer.Option(
        DemoConfig.test_sequences, min=1, help="Test sequences (five 100 ms windows each)."
    ),
    recording_s: float = typer.Option(
        DemoConfig.recording_s, min=0.2, help="Length of the streamed recording, seconds."
    ),
    finetune_minutes: float = typer.Option(
        DemoConfig.finetune_minutes,
        min=0.0,
        help="Also fine-tune the shipped weights on the CPU for this many minutes (0: skip).",
    ),
    seed: int = typer.Option(DemoConfig.seed, help="Seed of the simulated data."),
    workers: int = typer.Option(DemoConfig.workers, min=1, help="Simulator processes."),
) -> None:
    """Events in, angular velocity out: score the shipped SNN-6, CMax and the mean, then stream."""
    check_output_dir(out)
    run_demo(
        DemoConfig(
            out=out,
            test_sequences=test_sequences,
            recording_s=recording_s,
            finetune_minutes=finetune_minutes,
            seed=seed,
            workers=workers,
        )
    )
