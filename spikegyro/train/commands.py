"""``spikegyro train``: train SNN-6 or an ANN baseline from a preset plus command-line overrides.

Runs as one process, or as several under ``torchrun --nproc-per-node K -m spikegyro train ...``.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from spikegyro.errors import InputError
from spikegyro.train import distributed
from spikegyro.train.loop import TrainResult, resume_config, train
from spikegyro.train.presets import PRESETS, resolve_config


def _json_option(text: str | None, name: str) -> dict[str, Any] | None:
    if text is None:
        return None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"--{name} {text!r}: not valid JSON ({exc.msg}).") from None
    if not isinstance(value, dict):
        raise InputError(f"--{name} {text!r}: expected a JSON object like '{{\"key\": 1}}'.")
    return value


def throughput_line(result: TrainResult) -> str:
    """The run's samples/s against the bare step's, as ``train`` prints them."""
    line = (
        f"throughput: {result.samples_per_s:.1f} samples/s ({result.data_path} data path, "
        f"{result.compute} compute)"
    )
    if result.bare is not None:
        bare = result.bare
        line += (
            f", bare step {bare.samples_per_s:.1f} samples/s ({bare.ms_per_step:.1f} ms/step): "
            f"the run holds {result.samples_per_s / bare.samples_per_s:.0%} of it"
        )
    return line


def train_command(
    data: Path = typer.Option(None, "--data", help="Dataset folder with train/ and val/ splits."),
    out: Path = typer.Option(None, "--out", help="Run directory (default: runs/train-MODEL-TIME)."),
    preset: str = typer.Option("paper", help=f"Starting values: {', '.join(PRESETS)}."),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in --out from last.pt (options given override)."
    ),
    online: bool = typer.Option(
        None, "--online/--no-online", help="Simulate fresh training sequences on the fly."
    ),
    model: str = typer.Option(None, help="snn6, snn6-grid, ann6 or resnet50."),
    input: str = typer.Option(None, "--input", help="spikes (SNN), voxel or frames (ANNs)."),
    model_kwargs: str = typer.Option(None, help="Model constructor arguments as JSON."),
    init: Path = typer.Option(None, "--init", help="Start from this checkpoint's weights."),
    sensor_width: int = typer.Option(None, help="Width of the dataset's sensor, px."),
    sensor_height: int = typer.Option(None, help="Height of the dataset's sensor, px."),
    scale: float = typer.Option(None, help="Factor on event coordinates (0.5: 240x180->120x90)."),
    window_ms: int = typer.Option(None, help="Window length, ms."),
    num_bins: int = typer.Option(None, help="Voxel-grid bins (ANNs)."),
    target_ms: int = typer.Option(None, help="ANN prediction window, ms."),
    loss_start_step: int = typer.Option(None, help="First step (ms) counted by the loss."),
    train_window_ms: int = typer.Option(None, help="Training window length, ms (0 = --window-ms)."),
    train_loss_start_step: int = typer.Option(
        None, help="First step of training windows counted by the loss."
    ),
    batch_size: int = typer.Option(None, help="Windows per step, over all processes."),
    lr: float = typer.Option(None, help="Adam learning rate."),
    lr_schedule: str = typer.Option(None, help="constant or cosine."),
    lr_min_factor: float = typer.Option(None, help="Final lr of the cosine schedule, x lr."),
    warmup_steps: int = typer.Option(None, help="Linear learning-rate warm-up steps."),
    grad_clip: float = typer.Option(None, help="Max gradient norm (0 = off)."),
    iterations: int = typer.Option(None, help="Optimizer steps."),
    max_minutes: float = typer.Option(
        None, help="Stop gracefully once the run has trained this long, resumed minutes included."
    ),
    hflip: float = typer.Option(None, help="Probability of a horizontal flip."),
    vflip: float = typer.Option(None, help="Probability of a vertical flip."),
    time_reverse: float = typer.Option(None, help="Probability of time inversion."),
    event_keep_min: float = typer.Option(
        None, help="Event drop: each window keeps U(this, 1) of its events (1 = off)."
    ),
    noise_events_hz: float = typer.Option(
        None, help="Added background events per pixel per s, U(0, this) per window (0 = off)."
    ),
    centre_crop: float = typer.Option(
        None, help="Probability that a window keeps only a centred box of its events (0 = off)."
    ),
    freeze: int = typer.Option(
        None, help="SNN: keep the first N spiking layers' weights fixed (fine-tune the rest)."
    ),
    seed: int = typer.Option(None, help="Random seed (model init and samples)."),
    val_every: int = typer.Option(None, help="Validate and checkpoint every N steps."),
    val_windows: int = typer.Option(None, help="Validate on at most N windows (0 = all)."),
    val_sequences: int = typer.Option(None, help="Simulated validation sequences (online)."),
    log_every: int = typer.Option(None, help="Steps per log row."),
    num_workers: int = typer.Option(None, help="DataLoader workers per process."),
    threads: int = typer.Option(None, help="Torch CPU threads (0 = default)."),
    device: str = typer.Option(None, help="auto, cpu, cuda or cuda:K."),
    data_path: str = typer.Option(
        None, help="events (binned on the device), dense, or auto (events on CUDA)."
    ),
    amp: str = typer.Option(
        None, help="off, or bf16: the ANNs' forward passes in bfloat16 autocast (GPU speed)."
    ),
    compute: str = typer.Option(
        None, help="SNNs: sparse (event-driven CPU engine), dense (torch), or auto (sparse on a "
        "CPU in one process)."
    ),
    surrogate_cut: float = typer.Option(
        None, help="SNNs: zero the surrogate gradient below this share of its peak (0 = "
        "unbounded; default 0.05 sparse, 0 dense)."
    ),
    bare_steps: int = typer.Option(
        None, help="Bare training steps timed at the end, to compare with the run (0 = off)."
    ),
    sim: str = typer.Option(None, help="Simulator settings for --online, as JSON."),
    tensorboard: bool = typer.Option(None, "--tensorboard/--no-tensorboard", help="TB logs."),
) -> None:
    """Train a model; writes config.json, log.csv, last.pt, best.pt and loss.png to --out."""
    overrides: dict[str, Any] = {
        "data": None if data is None else str(data),
        "online": online,
        "model": model,
        "input": input,
        "model_kwargs": _json_option(model_kwargs, "model-kwargs"),
        "init": None if init is None else str(init),
        "freeze": freeze,
        "scale": scale,
        "window_ms": window_ms,
        "num_bins": num_bins,
        "target_ms": target_ms,
        "loss_start_step": loss_start_step,
        "train_window_ms": train_window_ms,
        "train_loss_start_step": train_loss_start_step,
        "batch_size": batch_size,
        "lr": lr,
        "lr_schedule": lr_schedule,
        "lr_min_factor": lr_min_factor,
        "warmup_steps": warmup_steps,
        "grad_clip": grad_clip,
        "iterations": iterations,
        "max_minutes": max_minutes,
        "hflip": hflip,
        "vflip": vflip,
        "time_reverse": time_reverse,
        "event_keep_min": event_keep_min,
        "noise_events_hz": noise_events_hz,
        "centre_crop": centre_crop,
        "seed": seed,
        "val_every": val_every,
        "val_windows": val_windows,
        "val_sequences": val_sequences,
        "log_every": log_every,
        "num_workers": num_workers,
        "threads": threads,
        "device": device,
        "data_path": data_path,
        "amp": amp,
        "compute": compute,
        "surrogate_cut": surrogate_cut,
        "bare_steps": bare_steps,
        "sim": _json_option(sim, "sim"),
        "tensorboard": tensorboard,
    }
    if (sensor_width is None) != (sensor_height is None):
        raise InputError("--sensor-width and --sensor-height go together.")
    if sensor_width is not None:
        overrides["sensor"] = (sensor_width, sensor_height)
    if resume:
        if out is None:
            raise InputError("--resume needs --out, the run directory to continue.")
        config = resume_config(out, overrides)
    else:
        if out is None:
            stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
            out = Path("runs") / f"train-{model or 'snn6'}-{stamp}"
        if (out / "last.pt").exists():
            raise InputError(f"{out}: already holds a run; pass --resume or another --out.")
        config = resolve_config(preset, {**overrides, "out": str(out)})
    if config.amp != "off" and distributed.pick_device(config.device).type == "cpu":
        Console(stderr=True).print(
            f"warning: --amp {config.amp} on a CPU: most CPUs have no bfloat16 units, so this is "
            "usually slower than float32 (it is meant for GPUs)."
        )
    result = train(config, resume=resume)
    if distributed.init_rank() == 0:
        console = Console()
        state = "done"
        if result.stopped_early:
            state = "interrupted" if result.interrupted else "stopped at the time budget"
        console.print(
            f"[bold]train[/] {config.model} {state}: {result.steps} steps in "
            f"{result.elapsed_s / 60:.1f} min, last loss {result.last_loss:.3f} rad/s"
        )
        if result.val:
            console.print(
                f"validation: median relative error {result.val['val_median_rel']:.3f}, mean "
                f"error {result.val['val_mean_err_deg']:.1f} deg/s (best median "
                f"{result.best_val_median_rel:.3f})"
            )
        console.print(throughput_line(result))
        console.print(f"run directory: {result.run_dir}")
        if result.interrupted:
            console.print(f"continue with: spikegyro train --out {result.run_dir} --resume")
    if result.interrupted:
        raise typer.Exit(130)
