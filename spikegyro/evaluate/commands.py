"""``spikegyro evaluate``, ``evaluate-real`` and ``report``: options in, library calls out.

The work is done by :func:`spikegyro.evaluate.simulated.run_evaluation` (a model and the mean
predictor on a dataset split), :func:`spikegyro.evaluate.real.run_real_evaluation` (SNN-6, CMax and
the mean predictor against a gyro on a real recording) and
:func:`spikegyro.evaluate.compare.compare_runs` (the paper's Table I over evaluated runs).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer
from rich.console import Console

from spikegyro import options
from spikegyro.checks import sensor_option
from spikegyro.evaluate.bins import parse_speed_bins
from spikegyro.evaluate.compare import compare_runs, console_summary, table_one
from spikegyro.evaluate.real import (
    DEFAULT_WINDOW_MS,
    OffsetConfig,
    RealEvalConfig,
    run_real_evaluation,
)
from spikegyro.evaluate.simulated import run_evaluation
from spikegyro.pretrained import checkpoint_help
from spikegyro.stream.predict import WARMUP_STEPS

SPEED_BINS_HELP = (
    "Speed bins of the per-bin metrics, deg/s: paper (0, 100, …, 500, inf), fine (0, 10, 25, 50, "
    "100, …: splits the slow motion of handheld cameras and robots) or edges '0,E1,E2,…'."
)


def evaluate(
    data: Path = typer.Option(..., "--data", help="Dataset folder (DIR/{train,val,test}/*.h5)."),
    checkpoint: Path = typer.Option(
        None,
        "--checkpoint",
        help=checkpoint_help("spikegyro checkpoint or the paper's official weights"),
    ),
    model: str = typer.Option(
        None, "--model", help="A non-learned method instead of a checkpoint: cmax."
    ),
    split: str = typer.Option("test", "--split", help="train, val or test."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    name: str = typer.Option(None, "--name", help="Model name in tables and legends."),
    batch_size: int = typer.Option(8, "--batch-size", min=1, help="Windows per forward pass."),
    device: str = typer.Option(None, "--device", help="cpu, cuda, cuda:1 (default: auto)."),
    limit: int = typer.Option(None, "--limit", min=1, help="Score only the first N windows."),
    example: list[int] = typer.Option(
        None, "--example", help="Window index for a qualitative figure (repeatable)."
    ),
    speed_bins: str = typer.Option("paper", "--speed-bins", help=SPEED_BINS_HELP),
    clock: str = options.CLOCK,
) -> None:
    """Score a model and the mean predictor: metrics.json, predictions, figures and a report."""
    run_evaluation(
        data,
        checkpoint,
        split,
        out,
        model=model,
        name=name,
        batch_size=batch_size,
        device=device,
        limit=limit,
        examples=example or None,
        speed_bins=parse_speed_bins(speed_bins),
        clock=clock,
    )


def report(
    run_dirs: list[Path] = typer.Argument(..., help="Output folders of `spikegyro evaluate`."),
    out: Path = typer.Option(..., "--out", help="Output folder for the comparison."),
    window: int = typer.Option(
        None,
        "--window",
        min=0,
        help="Test window of the qualitative figure (default: the one of median speed).",
    ),
) -> None:
    """The paper's Table I over evaluated runs: accuracy, training budget, energy per estimate,
    and its figures with all models side by side."""
    console = Console(stderr=True)
    models = compare_runs(list(run_dirs), out, window)
    console.print(console_summary(table_one(models)))
    console.print(
        f"wrote {out}/report.html, report.md, bins.png, boxes.png, window.png, comparison.json"
    )


def evaluate_real(
    recording: Path = typer.Argument(
        ..., help="Event file: .h5/.hdf5, .npz, events.txt (t x y p) or an ECD folder."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    gyro: Path = typer.Option(
        None,
        "--gyro",
        help="Gyro file: ECD imu.txt 't ax ay az gx gy gz' or 't wx wy wz' (rad/s, seconds); "
        "default the recording's own.",
    ),
    calib: Path = typer.Option(
        None,
        "--calib",
        help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt; taken from an ECD "
        "folder by default).",
    ),
    intrinsics: tuple[float, float, float, float] = options.INTRINSICS,
    checkpoint: Path = typer.Option(None, "--checkpoint", help=checkpoint_help("SNN checkpoint")),
    windows_ms: float = typer.Option(
        None,
        "--windows-ms",
        min=0.001,
        help=f"Windows by time, ms (default {DEFAULT_WINDOW_MS:g}).",
    ),
    windows_events: int = typer.Option(
        None, "--windows-events", min=1, help="Windows by event count instead of by time."
    ),
    start: float = options.START,
    end: float = options.END,
    warmup_ms: int = typer.Option(
        WARMUP_STEPS, "--warmup-ms", min=0, help="Steps (ms) after --start that are not scored."
    ),
    imu_to_camera: str = options.IMU_TO_CAMERA,
    gyro_offset: str = typer.Option(
        "0",
        "--gyro-offset",
        help="Milliseconds added to the gyro's timestamps, or 'auto' for the best fit "
        "(always reported).",
    ),
    max_offset_ms: float = typer.Option(
        OffsetConfig.max_offset_ms, "--max-offset-ms", min=0.5, help="Clock offsets searched, ±ms."
    ),
    mean_data: Path = typer.Option(
        None, "--mean-data", help="Dataset whose training mean the mean predictor answers (else 0)."
    ),
    speed_bins: str = typer.Option("paper", "--speed-bins", help=SPEED_BINS_HELP),
    width: int = options.WIDTH,
    height: int = options.HEIGHT,
    clock: str = options.CLOCK,
    pixels: str = options.PIXELS,
) -> None:
    """Score SNN-6, CMax and the mean predictor against a gyro on a real recording."""
    config = RealEvalConfig(
        windows_ms=DEFAULT_WINDOW_MS
        if windows_ms is None and windows_events is None
        else windows_ms,
        windows_events=windows_events,
        start_s=start,
        end_s=end,
        warmup_ms=warmup_ms,
        gyro_offset=gyro_offset,
        offset=replace(OffsetConfig(), max_offset_ms=max_offset_ms),
        speed_bins=parse_speed_bins(speed_bins),
        clock=clock,
        pixels=pixels,
    )
    run_real_evaluation(
        recording,
        out,
        gyro=gyro,
        calib=calib,
        intrinsics=intrinsics,
        checkpoint=checkpoint,
        imu_to_camera=imu_to_camera,
        mean_data=mean_data,
        config=config,
        sensor=sensor_option(width, height),
    )
