"""``spikegyro train``: train SNN-6 or an ANN baseline from a preset plus command-line overrides,
and ``spikegyro relay-log``: fold a segment of a run trained in segments into its joined log.

``train`` runs as one process, or as several under ``torchrun --nproc-per-node K -m spikegyro
train ...``. Its override options are generated from :class:`TrainConfig`'s fields (see
:data:`OPTION_HELP`), so an option and the field it sets cannot drift apart.
"""

from __future__ import annotations

import functools
import inspect
import json
import shutil
import types
import typing
from collections.abc import Callable
from dataclasses import fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NoReturn

import torch
import typer
from rich.console import Console

from spikegyro.errors import InputError
from spikegyro.models.registry import read_checkpoint
from spikegyro.options import END, INTRINSICS, START
from spikegyro.pretrained import DEFAULT_NAME, checkpoint_help
from spikegyro.train import distributed
from spikegyro.train.adapt import AdaptSettings, adapt, adapt_config, run_dir_of
from spikegyro.train.data import SampleError, sample_error_line
from spikegyro.train.loop import TrainResult, resume_config, train
from spikegyro.train.presets import PRESETS, SPARSE_DEFAULT_CUT, TrainConfig, resolve_config
from spikegyro.train.relay import STATE_FILES, append_segment, plot_relay
from spikegyro.train.throughput import cpu_has_bfloat16, resolve_amp

PRECISION = {"bf16": "bfloat16 autocast", "off": "float32"}


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


OPTION_HELP: dict[str, str] = {
    "data": "Dataset folder with train/ and val/ splits.",
    "online": "Simulate fresh training sequences on the fly.",
    "model": "snn6, snn6-grid, ann6 or resnet50.",
    "input": "spikes (SNN), voxel or frames (ANNs).",
    "model_kwargs": "Model constructor arguments as JSON.",
    "init": checkpoint_help("Start from these weights", None),
    "freeze": "SNN: keep the first N spiking layers' weights fixed (fine-tune the rest).",
    "learn_tau": "SNN: also learn the time constants τs, τr of every layer (and the readout's).",
    "scale": "Factor on event coordinates (0.5: 240x180->120x90).",
    "window_ms": "Window length, ms.",
    "num_bins": "Voxel-grid bins (ANNs).",
    "target_ms": "ANN prediction window, ms.",
    "loss_start_step": "First step (ms) counted by the loss.",
    "train_window_ms": "Training window length, ms (0 = --window-ms).",
    "train_loss_start_step": "First step of training windows counted by the loss.",
    "batch_size": "Windows per step, over all processes.",
    "lr": "Adam learning rate.",
    "lr_schedule": "constant or cosine.",
    "lr_min_factor": "Final lr of the cosine schedule, x lr.",
    "warmup_steps": "Linear learning-rate warm-up steps.",
    "grad_clip": "Max gradient norm (0 = off).",
    "iterations": "Optimizer steps.",
    "max_minutes": "Stop gracefully once the run has trained this long, resumed minutes included.",
    "patience": "Stop once this many validations in a row have not improved on the best (0 = off).",
    "hflip": "Probability of a horizontal flip.",
    "vflip": "Probability of a vertical flip.",
    "time_reverse": "Probability of time inversion.",
    "event_keep_min": "Event drop: each window keeps U(this, 1) of its events (1 = off).",
    "noise_events_hz": (
        "Added background events per pixel per s, U(0, this) per window (0 = off)."
    ),
    "centre_crop": "Probability that a window keeps only a centred box of its events (0 = off).",
    "seed": "Random seed (model init and samples).",
    "val_every": "Validate and checkpoint every N steps.",
    "val_windows": "Validate on at most N windows (0 = all).",
    "val_sequences": "Simulated validation sequences (online).",
    "log_every": "Steps per log row.",
    "num_workers": "DataLoader workers per process (at most the cores available).",
    "threads": "Torch CPU threads (0 = default).",
    "device": "auto, cpu, cuda or cuda:K.",
    "data_path": "events (binned where the model runs), dense, or auto (events on CUDA and for "
    "the event-driven CPU engine).",
    "amp": "off, or bf16: the ANNs' forward passes in bfloat16 autocast (GPUs; CPUs with bf16).",
    "compute": "SNNs: sparse (event-driven CPU engine), dense (torch), or auto (sparse on a CPU "
    "in one process).",
    "surrogate_cut": "SNNs: zero the surrogate gradient below this share of its peak (0 = "
    f"unbounded; default {SPARSE_DEFAULT_CUT} sparse, 0 dense).",
    "bare_steps": "Bare training steps timed at the end, to compare with the run (0 = off).",
    "sim": "Simulator settings for --online, as JSON.",
    "tensorboard": "TB logs.",
    "real": "A real recording to learn from without a gyro (repeat for several; any format).",
    "real_calib": "Its calibration: a file or fx,fy,cx,cy in pixels (one for all, or one per "
    "--real; default: an Event Camera Dataset folder's calib.txt).",
    "real_share": "Share of each batch drawn from --real (1: real windows only).",
    "real_loss": "contrast (sharpness of the events warped by the output) or teacher "
    "(contrast maximization's estimates as labels).",
    "real_weight": "Weight of the real windows' loss.",
    "real_span_ms": "Events of at least this many ms before each scored step are warped.",
    "real_holdout": "Last share of each real recording, held out for validation.",
    "real_start": "Use each real recording from this many seconds after its first event.",
    "real_end": "... to this many seconds after it (default: its end).",
    "clock": "SNN clock: paper (1 ms steps) or events:N[:MIN-MAX] (a step closes after N "
    "events, within MIN-MAX ms; window lengths then count steps).",
}
"""TrainConfig field -> help of its option ``--FIELD-NAME``, which overrides the preset's (or the
resumed run's) value when given. The option's type is the field's: a bool is a ``--x/--no-x``
flag, a dict is JSON text, and the fields in :data:`PATH_FIELDS` are paths."""

COMMAND_FIELDS: dict[str, tuple[str, ...]] = {
    # The TrainConfig fields that train_command sets from its own parameters instead:
    "preset": ("preset",),  # names the starting values, which the overrides go on top of
    "out": ("out", "resume"),  # has a default of its own, and names the run --resume continues
    "sensor": ("sensor_width", "sensor_height"),  # a (width, height) pair: two options
}
"""TrainConfig field -> the parameters of :func:`train_command` that give it."""

PATH_FIELDS = ("data", "init")
"""The str fields that name files or folders: their options take paths."""


@functools.cache
def _field_kind(name: str) -> type:
    """The type of TrainConfig's field ``name``, without its ``| None`` and type arguments."""
    hint = typing.get_type_hints(TrainConfig)[name]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        hint = next(arg for arg in typing.get_args(hint) if arg is not type(None))
    return typing.get_origin(hint) or hint


def _config_option(name: str) -> inspect.Parameter:
    """The keyword parameter of ``train_command`` for option ``--NAME`` (None: not given)."""
    kind = _field_kind(name)
    flag = name.replace("_", "-")
    if kind is dict:
        kind = str
    elif kind is list:
        kind = list[str]  # a repeatable option
    elif name in PATH_FIELDS:
        kind = Path
    declaration = f"--{flag}/--no-{flag}" if kind is bool else f"--{flag}"
    option = typer.Option(None, declaration, help=OPTION_HELP[name])
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=option, annotation=kind)


def _with_config_options(command: Callable[..., None]) -> Callable[..., None]:
    """Give ``command`` (whose ``**options`` take the overrides) an option for every field in
    :data:`OPTION_HELP`, its own parameters standing in for :data:`COMMAND_FIELDS`, all in the
    order of TrainConfig's fields; Typer reads the options from the signature."""
    own = inspect.signature(command, eval_str=True).parameters
    parameters = []
    for name in (f.name for f in fields(TrainConfig)):
        if name in OPTION_HELP:
            parameters.append(_config_option(name))
        for given in COMMAND_FIELDS.get(name, ()):
            parameters.append(own[given].replace(kind=inspect.Parameter.KEYWORD_ONLY))
    command.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in parameters}
    return command


def _overrides(
    options: dict[str, Any], sensor_width: int | None, sensor_height: int | None
) -> dict[str, Any]:
    """The TrainConfig values given on the command line (None where an option was not)."""
    overrides: dict[str, Any] = {}
    for name, value in options.items():
        if value is not None and _field_kind(name) is dict:
            value = _json_option(value, name.replace("_", "-"))
        if isinstance(value, (list, tuple)):
            value = [str(v) for v in value] or None  # a repeatable option given no time
        overrides[name] = str(value) if isinstance(value, Path) else value
    if (sensor_width is None) != (sensor_height is None):
        raise InputError("--sensor-width and --sensor-height go together.")
    if sensor_width is not None:
        overrides["sensor"] = (sensor_width, sensor_height)
    return overrides


def _run_config(
    preset: str, out: Path | None, resume: bool, overrides: dict[str, Any]
) -> TrainConfig:
    """The configuration of the run: the stored one on resume, else the preset's."""
    if resume:
        if out is None:
            raise InputError("--resume needs --out, the run directory to continue.")
        return resume_config(out, overrides)
    if out is None:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
        out = Path("runs") / f"train-{overrides.get('model') or 'snn6'}-{stamp}"
    if (out / "last.pt").exists():
        raise InputError(f"{out}: already holds a run; pass --resume or another --out.")
    return resolve_config(preset, {**overrides, "out": str(out)})


def precision_line(amp: str, device: torch.device) -> str:
    """The one line an ANN run starts with: the precision it trains in, and why."""
    resolved = resolve_amp(amp, "voxel", device)
    native = device.type == "cpu" and cpu_has_bfloat16()
    if resolved == "bf16" and device.type == "cpu" and not native:
        return (
            "warning: --amp bf16 on a CPU without bfloat16 instructions (AVX-512 BF16 or AMX): "
            "usually several times slower than float32 here (it is meant for GPUs)."
        )
    if amp != "auto":
        return f"precision: {PRECISION[resolved]} (--amp {amp})"
    if resolved == "bf16":
        return f"precision: {PRECISION[resolved]} on this CPU's bfloat16 units (--amp off: float32)"
    why = "on a GPU autocast is opt-in" if device.type != "cpu" else "no bfloat16 instructions"
    return f"precision: float32, {why} (--amp bf16: bfloat16 autocast)"


def _report(config: TrainConfig, result: TrainResult) -> None:
    """What the run did, where it is, and how to continue it when it was interrupted."""
    console = Console()
    state = "done"
    if result.stopped_early:
        state = "interrupted" if result.interrupted else "stopped at the time budget"
        if result.out_of_patience:
            state = (
                f"stopped: validation has not improved for {config.patience} validations "
                f"(best at step {result.best_step})"
            )
    console.print(
        f"[bold]train[/] {config.model} {state}: {result.steps} steps in "
        f"{result.elapsed_s / 60:.1f} min, last loss {result.last_loss:.3f} rad/s"
    )
    val = result.val
    if "val_median_rel" in val:
        best = "" if config.real else f" (best median {result.best_score:.3f})"
        console.print(
            f"validation: median relative error {val['val_median_rel']:.3f}, mean "
            f"error {val['val_mean_err_deg']:.1f} deg/s{best}"
        )
    if "val_real_gain" in val:
        console.print(
            f"held-out real windows: contrast gain {val['val_real_gain']:.3f} (ω = 0: 1; "
            f"contrast maximization: {val['val_real_gain_cmax']:.3f}; best "
            f"{-result.best_score:.3f})"
        )
    console.print(throughput_line(result))
    console.print(f"run directory: {result.run_dir}")
    if result.interrupted:
        console.print(f"continue with: spikegyro train --out {result.run_dir} --resume")


def _stop_on_bad_sample(config: TrainConfig, exc: SampleError) -> NoReturn:
    """End a run whose data failed: one line with the cause, the checkpoint that is kept and the
    command that continues from it; exit code 1."""
    run = Path(config.out)
    last = run / "last.pt"
    if last.exists():
        step = int(read_checkpoint(last)["extra"].get("step", 0))
        kept = (
            f"its last checkpoint {last} (step {step:,}) is kept; after fixing the cause, "
            f"continue with: spikegyro train --resume --out {run}"
        )
    else:
        kept = "no checkpoint was written yet; after fixing the cause, run the command again"
    if distributed.init_rank() == 0:
        cause = sample_error_line(exc)
        typer.echo(f"error: training stopped, a data worker failed: {cause}; {kept}", err=True)
    raise typer.Exit(1)


@_with_config_options
def train_command(
    preset: str = typer.Option("paper", help=f"Starting values: {', '.join(PRESETS)}."),
    out: Path = typer.Option(None, "--out", help="Run directory (default: runs/train-MODEL-TIME)."),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in --out from last.pt (options given override)."
    ),
    sensor_width: int = typer.Option(None, help="Width of the dataset's sensor, px."),
    sensor_height: int = typer.Option(None, help="Height of the dataset's sensor, px."),
    **options: Any,
) -> None:
    """Train a model; writes config.json, log.csv, last.pt, best.pt and loss.png to --out."""
    config = _run_config(preset, out, resume, _overrides(options, sensor_width, sensor_height))
    device = distributed.pick_device(config.device)
    if config.input != "spikes" and distributed.init_rank() == 0:
        Console(stderr=True).print(precision_line(config.amp, device), highlight=False)
    try:
        result = train(config, resume=resume)
    except SampleError as exc:
        _stop_on_bad_sample(config, exc)
    if distributed.init_rank() == 0:
        _report(config, result)
    if result.interrupted:
        raise typer.Exit(130)


def relay_log_command(
    run_dir: Path = typer.Argument(..., help="The `spikegyro train` run of the new segment."),
    relay: Path = typer.Option(
        None,
        "--relay",
        help="Folder of the joined log (default: the run directory); the run's resume state is "
        "copied there when it is another folder.",
    ),
    note: str = typer.Option("", "--note", help="What this segment did (data, hardware)."),
) -> None:
    """Fold a training segment into the joined log: its rows, the resume state and the curve."""
    relay = run_dir if relay is None else relay
    entry = append_segment(run_dir, relay, note)
    if relay.resolve() != run_dir.resolve():
        for name in STATE_FILES:
            if (run_dir / name).exists():
                shutil.copy2(run_dir / name, relay / name)
    plot_relay(relay / "relay_log.csv", relay / "relay_curve.png")
    typer.echo(
        f"segment {entry['segment']}: steps {entry['first_step']:,}-{entry['last_step']:,}, "
        f"{entry['train_s']:.0f} s; wrote {relay}/relay_log.csv, relay.json, relay_curve.png"
    )


def adapt_command(
    recordings: list[Path] = typer.Argument(..., help="Your camera's recordings (any format)."),
    out: Path = typer.Option(..., "--out", "-o", help="The adapted checkpoint to write (.pt)."),
    calib: Path = typer.Option(
        None, "--calib", help="Calibration file (fx fy cx cy k1 k2 p1 p2 k3)."
    ),
    intrinsics: tuple[float, float, float, float] = INTRINSICS,
    checkpoint: str = typer.Option(
        DEFAULT_NAME, "--checkpoint", help=checkpoint_help("Start from")
    ),
    start: float = START,
    end: float = END,
    max_minutes: float = typer.Option(10.0, "--max-minutes", help="Training time budget."),
    loss: str = typer.Option("contrast", "--loss", help="contrast or teacher."),
    lr: float = typer.Option(1e-4, "--lr", help="Adam learning rate."),
    batch_size: int = typer.Option(4, "--batch-size", help="Real windows per step."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the windows drawn."),
) -> None:
    """Fine-tune the SNN on your own recordings without a gyro (self-supervised, by contrast)."""
    if calib is not None and intrinsics is not None:
        raise InputError("--calib and --intrinsics: give one of them, not both.")
    camera = str(calib) if calib is not None else None
    if intrinsics is not None:
        camera = ",".join(f"{v:g}" for v in intrinsics)
    settings = AdaptSettings([str(r) for r in recordings], camera, checkpoint, out, start, end,
                             max_minutes, loss, lr, batch_size, seed=seed)  # fmt: skip
    adapted = adapt(settings, adapt_config(settings))
    console = Console()
    result = adapted.result
    console.print(
        f"[bold]adapt[/] {result.steps} steps in {result.elapsed_s / 60:.1f} min; contrast gain "
        f"on the held-out windows: {adapted.gain_start:.3f} -> {adapted.gain_end:.3f} (ω = 0: 1; "
        f"contrast maximization: {adapted.gain_cmax:.3f})"
    )
    if adapted.kept_start:
        console.print("no validation beat the starting weights: the checkpoint holds them")
    console.print(f"wrote {out} (run files in {run_dir_of(out)}); use it with --checkpoint {out}")
    if result.interrupted:
        raise typer.Exit(130)
