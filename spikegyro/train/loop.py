"""The training loop: data, optimizer, validation, checkpoints, logs, resume and DDP.

A run directory holds ``config.json`` (the resolved :class:`TrainConfig`), ``log.csv`` (one row
per ``log_every`` steps: step, loss, lr, validation metrics, time), ``last.pt`` and ``best.pt``
(:func:`spikegyro.models.registry.save_checkpoint`; best = lowest validation median relative
error), ``resume.pt`` (optimizer, scheduler, step, RNG states) and ``loss.png`` at the end.

Data are indexed by sample number (see :class:`~spikegyro.train.data.TrainingSamples`): step s
reads samples ``s*B .. s*B+B-1`` and process r of K takes its slice ``r*B/K ..`` of them, so a
resumed or distributed run sees the same batches as one uninterrupted single-process run.
"""

from __future__ import annotations

import functools
import math
import random
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, Sampler

from spikegyro.errors import InputError
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import build_model, save_checkpoint
from spikegyro.train import distributed
from spikegyro.train.augment import AugmentConfig
from spikegyro.train.data import (
    FileSource,
    InputSpec,
    OnlineSource,
    TrainingSamples,
    Window,
    device_batch,
    events_on_device,
    fixed_windows,
    sequence_windows,
    windows_fingerprint,
)
from spikegyro.train.infer import predict_windows
from spikegyro.train.interrupt import GracefulStop, ignore_interrupts
from spikegyro.train.loss import validation_metrics
from spikegyro.train.presets import TrainConfig, load_config
from spikegyro.train.runfiles import (
    ProgressBar,
    RunFiles,
    check_time_budget,
    load_init,
    load_resume,
    rng_states,
    tensorboard,
)
from spikegyro.train.throughput import BareStep, RunClock, bare_step_rate, train_step


@dataclass
class TrainResult:
    """What a run produced (returned on every process; files are written by rank 0)."""

    run_dir: Path
    steps: int
    elapsed_s: float
    last_loss: float
    best_val_median_rel: float
    val: dict[str, float] = field(default_factory=dict)
    stopped_early: bool = False
    samples_per_s: float = math.nan  # steady state, without validation (see RunClock)
    bare: BareStep | None = None  # the bare step of one process's share of the batch
    data_path: str = "dense"
    interrupted: bool = False  # stopped by Ctrl-C (see spikegyro.train.interrupt)
    compute: str = "dense"  # how the training step ran: "sparse" (event engine) or "dense"


# ------------------------------------------------------------------------------ components


def input_spec_of(config: TrainConfig) -> InputSpec:
    return InputSpec.for_representation(
        config.input,
        sensor=config.sensor,
        scale=config.scale,
        window_ms=config.window_ms,
        num_bins=config.num_bins,
        target_ms=config.target_ms,
    )


def model_kwargs_of(config: TrainConfig, spec: InputSpec) -> dict[str, Any]:
    """Constructor arguments: ANNs need their input planes; the rest comes from the config."""
    kwargs = dict(config.model_kwargs or {})
    if spec.output == "window_mean":
        kwargs.setdefault("in_channels", spec.in_channels)
    return kwargs


def online_simulator(config: TrainConfig, split: str = "train") -> functools.partial:
    """``index -> Recording`` for online mode (a picklable partial of ``simulate_sequence``).

    Sequences last one window unless ``config.sim`` sets ``duration_ms`` (only one window is
    drawn from each), and the camera is scaled to ``config.sensor`` if it differs.
    """
    from spikegyro.sim.camera import Camera  # the simulator is only needed in online mode
    from spikegyro.sim.dataset import SimConfig, simulate_sequence

    base = SimConfig(duration_ms=max(config.window_ms, config.train_window_ms)).to_dict()
    for key, value in (config.sim or {}).items():
        if key not in base:
            raise InputError(f"--sim: unknown simulator setting '{key}'; see SimConfig.")
        base[key] = {**base[key], **value} if isinstance(base[key], dict) else value
    try:
        sim_config = SimConfig.from_dict(base)
    except (TypeError, ValueError) as exc:
        raise InputError(f"--sim {config.sim}: not a valid simulator setting ({exc}).") from None
    cam = sim_config.camera
    if (cam.width, cam.height) != config.sensor:
        sim_config = replace(sim_config, camera=Camera.scaled(*config.sensor, fov_of=cam))
    return functools.partial(simulate_sequence, sim_config, seed=config.seed, split=split)


def training_samples(
    config: TrainConfig, spec: InputSpec, *, events: bool = False
) -> TrainingSamples:
    """Random training windows of ``train_window_ms``, augmented, encoded as ``spec`` says
    (or, with ``events``, as event lists to be binned on the device)."""
    spec = replace(spec, window_ms=config.train_window_ms)
    if config.online:
        source = OnlineSource(online_simulator(config), config.train_window_ms)
    else:
        source = FileSource.from_split(config.data, "train", config.train_window_ms)
    augment = AugmentConfig.of(config)
    return TrainingSamples(
        source, spec, seed=config.seed, augment=augment if augment.enabled else None, events=events
    )


def validation_windows(config: TrainConfig) -> list[Window]:
    """Fixed validation windows: the ``val`` split, or simulated sequences in online mode."""
    if config.data:
        windows = fixed_windows(config.data, "val", config.window_ms)
    else:
        simulate = online_simulator(config, split="val")
        windows = [
            w
            for i in range(config.val_sequences)
            for w in sequence_windows(simulate(i), config.window_ms, f"online-val:{i}")
        ]
    if config.val_windows and len(windows) > config.val_windows:
        # an even spread over sequences and positions, the same every time
        pick = np.linspace(0, len(windows) - 1, config.val_windows).round().astype(int)
        windows = [windows[i] for i in pick]
    return windows


class StepSampler(Sampler[int]):
    """Sample indices of steps ``start .. stop-1`` for one process (see the module docstring)."""

    def __init__(self, start: int, stop: int, global_batch: int, rank: int, world: int) -> None:
        self.start, self.stop = start, stop
        self.local = global_batch // world
        self.global_batch = global_batch
        self.rank = rank

    def __iter__(self) -> Iterator[int]:
        for step in range(self.start, self.stop):
            base = step * self.global_batch + self.rank * self.local
            yield from range(base, base + self.local)

    def __len__(self) -> int:
        return (self.stop - self.start) * self.local


def _worker_init(_: int) -> None:
    torch.set_num_threads(1)  # workers encode events; the main process owns the cores
    ignore_interrupts()


def lr_factor(step: int, config: TrainConfig) -> float:
    """Multiplier of the base learning rate at ``step``: linear warm-up, then flat or cosine."""
    if config.warmup_steps and step < config.warmup_steps:
        return (step + 1) / config.warmup_steps
    if config.lr_schedule == "constant":
        return 1.0
    span = max(1, config.iterations - config.warmup_steps)
    progress = min(1.0, (step - config.warmup_steps) / span)
    low = config.lr_min_factor
    return low + (1 - low) * 0.5 * (1 + math.cos(math.pi * progress))


def validate(
    model: nn.Module, spec: InputSpec, windows: list[Window], config: TrainConfig, device
) -> dict[str, float]:
    was_training = model.training
    prediction = predict_windows(model, spec, windows, batch_size=config.batch_size, device=device)
    model.train(was_training)
    truth = np.stack([w.omega for w in windows])
    return validation_metrics(prediction, truth, config.loss_start_step)


def resolve_compute(config: TrainConfig, ctx: distributed.DistContext) -> str:
    """"sparse" or "dense": how this run computes its training steps (see ``TrainConfig``)."""
    if config.input != "spikes":
        return "dense"
    if config.compute == "sparse" and ctx.device.type != "cpu":
        raise InputError(
            f"--compute sparse on {ctx.device}: the event-driven engine runs on the CPU; use "
            "--compute dense on a GPU."
        )
    if config.compute == "sparse" and ctx.distributed:
        raise InputError(
            "--compute sparse under torchrun: the event-driven engine trains in one process "
            "(its threads share the batch); run without torchrun or use --compute dense."
        )
    if config.compute == "auto":
        return "sparse" if ctx.device.type == "cpu" and not ctx.distributed else "dense"
    return config.compute


def configure_compute(model: nn.Module, config: TrainConfig, ctx: distributed.DistContext) -> str:
    """Give an SNN the surrogate cut and engine of the run; returns "sparse" or "dense"."""
    compute = resolve_compute(config, ctx)
    if config.input == "spikes":
        model.set_surrogate_cut(config.resolved_cut(compute))
        threads = config.threads or torch.get_num_threads()
        model.use_event_engine(threads if compute == "sparse" else None)
    return compute


def seed_everything(seed: int) -> None:
    """Seed the global generators (model init); samples use their own per-index generators."""
    random.seed(seed)
    torch.manual_seed(seed)


RUN_FIXED = ("model", "input", "model_kwargs", "freeze")
"""Options a resumed run cannot change."""


def resume_config(run_dir: Path, overrides: dict[str, Any] | None = None) -> TrainConfig:
    """The saved configuration of a run, with ``overrides`` (e.g. more iterations) applied."""
    path = run_dir / "config.json"
    if not path.exists():
        raise InputError(f"{run_dir}: no config.json; is this a training run directory?")
    data = load_config(path.read_text()).as_dict()
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    for name in RUN_FIXED:  # the saved weights and optimizer state belong to these
        if name in given and given[name] != data[name]:
            raise InputError(
                f"--resume: {run_dir} was trained with {name} = {data[name]!r}, not "
                f"{given[name]!r}; start a new run from it with --init {run_dir / 'last.pt'}."
            )
    data.update(given)
    data["sensor"] = tuple(data["sensor"])
    data["out"] = str(run_dir)  # the folder may have been moved since
    return TrainConfig(**data)


# ------------------------------------------------------------------------------------ loop


def train(config: TrainConfig, *, resume: bool = False, progress: bool = True) -> TrainResult:
    """Train a model as ``config`` says; under torchrun every process calls this.

    Args:
        config: the resolved configuration (``config.out`` is the run directory).
        resume: continue from ``out/last.pt`` + ``out/resume.pt`` (must exist).
        progress: show a progress bar on rank 0.
    """
    if not config.out:
        raise InputError("train: give a run directory (--out DIR).")
    ctx = distributed.init_distributed(config.device)
    try:
        return _train(config, ctx, resume=resume, progress=progress)
    finally:
        distributed.shutdown(ctx)


def _train(
    config: TrainConfig, ctx: distributed.DistContext, *, resume: bool, progress: bool
) -> TrainResult:
    if config.batch_size % ctx.world_size:
        raise InputError(
            f"--batch-size {config.batch_size} is not divisible by the {ctx.world_size} "
            "processes; each process takes an equal share of the batch."
        )
    if config.threads:
        torch.set_num_threads(config.threads)
    files = RunFiles(Path(config.out))
    spec = input_spec_of(config)
    kwargs = model_kwargs_of(config, spec)
    seed_everything(config.seed)
    model = build_model(config.model, **kwargs)
    before = load_init(model, config) if config.init and not resume else {}
    model = model.to(ctx.device)
    compute = configure_compute(model, config, ctx)
    trained = model.freeze(config.freeze) if config.freeze else list(model.parameters())
    optimizer = torch.optim.Adam(trained, lr=config.lr)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: lr_factor(s, config))

    start_step, best, elapsed0, best_on = 0, math.inf, 0.0, ""
    if resume:
        start_step, best, elapsed0, best_on, before = load_resume(
            files, model, optimizer, scheduler, ctx.device
        )
        check_time_budget(config.max_minutes, elapsed0)
    net: nn.Module = model
    if ctx.distributed:
        ids = [ctx.device.index] if ctx.device.type == "cuda" else None
        net = DistributedDataParallel(model, device_ids=ids)

    events = events_on_device(ctx.device, config.data_path)
    samples = training_samples(config, spec, events=events)
    val_windows = validation_windows(config) if ctx.is_main else []
    val_id = windows_fingerprint(val_windows)
    if ctx.is_main and best_on != val_id and math.isfinite(best):
        # A best score on other validation data must not block the new data's best.pt.
        print(
            f"validation data differ from the resumed run's: best {best:.4f} forgotten",
            file=sys.stderr,
        )
        best = math.inf
    if ctx.is_main:
        files.write_config(config)
        files.start_log(start_step)
    writer = tensorboard(files.dir) if config.tensorboard and ctx.is_main else None

    loader = DataLoader(
        samples,
        batch_size=config.batch_size // ctx.world_size,
        sampler=StepSampler(
            start_step, config.iterations, config.batch_size, ctx.rank, ctx.world_size
        ),
        num_workers=config.num_workers,
        collate_fn=samples.collate,
        worker_init_fn=_worker_init if config.num_workers else None,
        persistent_workers=False,
        pin_memory=ctx.device.type == "cuda",
    )
    bar = ProgressBar(config, start_step, enabled=progress and ctx.is_main)
    clock = RunClock(config.batch_size)
    t0 = time.monotonic() - elapsed0
    step, loss_sum, loss_n, last_loss, val = start_step, 0.0, 0, math.nan, {}
    stopped_early, amp = False, config.amp != "off"
    net.train()
    with bar, GracefulStop() as interrupt:
        for inputs, targets in loader:
            x, y = device_batch(inputs, targets, spec, ctx.device)
            loss = train_step(net, optimizer, x, y, config.train_loss_start_step, config.grad_clip,
                              amp)  # fmt: skip
            scheduler.step()
            step += 1
            loss_sum += float(loss)
            loss_n += 1
            clock.step()
            over_time = config.max_minutes > 0 and time.monotonic() - t0 > 60 * config.max_minutes
            stop = distributed.agree(over_time or interrupt.requested, ctx)
            final = stop or step == config.iterations
            row: dict[str, Any] = {}
            if step % config.log_every == 0 or final:
                last_loss = distributed.mean_across(loss_sum / loss_n, ctx)
                loss_sum, loss_n = 0.0, 0
                elapsed = time.monotonic() - t0
                row = {
                    "step": step,
                    "loss": f"{last_loss:.6g}",
                    "lr": f"{scheduler.get_last_lr()[0]:.6g}",
                    "elapsed_s": f"{elapsed:.1f}",
                    "samples_per_s": f"{(step - start_step) * config.batch_size / max(elapsed - elapsed0, 1e-9):.2f}",  # noqa: E501
                }
            if step % config.val_every == 0 or final:
                with clock.paused():
                    if ctx.is_main:
                        val = validate(model, spec, val_windows, config, ctx.device)
                        row.update({k: f"{v:.6g}" for k, v in val.items()})
                        better = val["val_median_rel"] < best
                        best = min(best, val["val_median_rel"])
                        _checkpoint(files, model, config, spec, kwargs, optimizer, scheduler, step,
                                    (best, val_id), time.monotonic() - t0, val, better,
                                    before)  # fmt: skip
                    distributed.barrier(ctx)
            if row and ctx.is_main:
                row.setdefault("step", step)
                files.append_log(row)
                if writer is not None:
                    for k, v in row.items():
                        if k != "step" and v != "":
                            writer.add_scalar(k, float(v), step)
            bar.update(step, last_loss, val)
            if stop:
                stopped_early = step < config.iterations
                break
    elapsed = time.monotonic() - t0
    bare = None
    if config.bare_steps and step > start_step and not interrupt.requested:
        bare = bare_step_rate(
            model, x, y, windows=config.batch_size // ctx.world_size, lr=config.lr,
            loss_start_step=config.train_loss_start_step, grad_clip=config.grad_clip,
            steps=config.bare_steps, amp=amp,
        )  # fmt: skip
    data_path = "events" if events else "dense"
    if ctx.is_main:
        if writer is not None:
            writer.close()
        files.plot_curve()
        files.write_throughput(clock.samples_per_s, bare, data_path, ctx.world_size)
    return TrainResult(files.dir, step, elapsed, last_loss, best, val, stopped_early,
                       clock.samples_per_s, bare, data_path,
                       interrupt.requested and stopped_early, compute)  # fmt: skip


def _checkpoint(
    files: RunFiles,
    model: nn.Module,
    config: TrainConfig,
    spec: InputSpec,
    kwargs: dict[str, Any],
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    step: int,
    best: tuple[float, str],
    elapsed_s: float,
    val: dict[str, float],
    better: bool,
    before: dict[str, float],
) -> None:
    """Write last.pt (and best.pt when ``better``) and resume.pt; ``best`` is (the lowest
    validation median relative error, the :func:`windows_fingerprint` it was measured on);
    ``before``: the training of the checkpoint this run started from (``--init``)."""
    extra = {"config": config.as_dict(), "step": step, "metrics": val, "elapsed_s": elapsed_s,
             "before": before}  # fmt: skip
    save = functools.partial(
        save_checkpoint, model=model, name=config.model, model_kwargs=kwargs,
        input_spec=spec.as_dict(), extra=extra,
    )  # fmt: skip
    save(files.last)
    if better:
        save(files.best)
    state = {
        "step": step,
        "best": best[0],
        "best_on": best[1],
        "elapsed_s": elapsed_s,
        "optimizer": optimizer.state_dict(),
        "scheduler": scheduler.state_dict(),
        "rng": rng_states(),
    }
    with atomic_path(files.resume) as tmp:
        torch.save(state, tmp)
