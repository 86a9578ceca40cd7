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
import os
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
from spikegyro.events.clock import Clock
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import build_model, save_checkpoint
from spikegyro.train import distributed
from spikegyro.train.augment import AugmentConfig
from spikegyro.train.data import (
    EventBatch,
    FileSource,
    InputSpec,
    OnlineSource,
    TrainingSamples,
    Window,
    clocked_sequence_windows,
    device_batch,
    events_on_device,
    fixed_windows,
    sequence_windows,
    windows_fingerprint,
)
from spikegyro.train.infer import predict_windows
from spikegyro.train.interrupt import GracefulStop, ignore_interrupts
from spikegyro.train.loss import validation_metrics
from spikegyro.train.memory import keep_freed_memory
from spikegyro.train.presets import TrainConfig, load_config
from spikegyro.train.real import RealValidation, RealWindows, load_recordings, model_inputs
from spikegyro.train.runfiles import (
    ProgressBar,
    RunFiles,
    check_time_budget,
    load_init,
    load_resume,
    rng_states,
    tensorboard,
)
from spikegyro.train.selfsup import ContrastLossConfig, batch_loss
from spikegyro.train.throughput import (
    BareStep,
    RunClock,
    bare_step_rate,
    resolve_amp,
    train_step,
)


@dataclass
class TrainResult:
    """What a run produced (returned on every process; files are written by rank 0)."""

    run_dir: Path
    steps: int
    elapsed_s: float
    last_loss: float
    best_score: float  # what best.pt minimizes (see selection_score)
    val: dict[str, float] = field(default_factory=dict)
    stopped_early: bool = False
    samples_per_s: float = math.nan  # steady state, without validation (see RunClock)
    bare: BareStep | None = None  # the bare step of one process's share of the batch
    data_path: str = "dense"
    interrupted: bool = False  # stopped by Ctrl-C (see spikegyro.train.interrupt)
    compute: str = "dense"  # how the training step ran: "sparse" (event engine) or "dense"
    val_start: dict[str, float] = field(default_factory=dict)  # real windows, before step 1
    best_step: int = 0  # the step of best.pt
    out_of_patience: bool = False  # stopped by --patience


# ------------------------------------------------------------------------------ components


def input_spec_of(config: TrainConfig) -> InputSpec:
    return InputSpec.for_representation(
        config.input,
        sensor=config.sensor,
        scale=config.scale,
        window_ms=config.window_ms,
        num_bins=config.num_bins,
        target_ms=config.target_ms,
        clock=Clock.parse(config.clock),
    )


def model_kwargs_of(config: TrainConfig, spec: InputSpec) -> dict[str, Any]:
    """Constructor arguments: ANNs need their input planes; the rest comes from the config."""
    kwargs = dict(config.model_kwargs or {})
    if spec.output == "window_mean":
        kwargs.setdefault("in_channels", spec.in_channels)
    if config.learn_tau:
        kwargs["learn_tau"] = True
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
    clock = Clock.parse(config.clock)
    if config.online:
        source = OnlineSource(online_simulator(config), config.train_window_ms, clock)
    else:
        source = FileSource.from_split(config.data, "train", config.train_window_ms, clock)
    augment = AugmentConfig.of(config)
    return TrainingSamples(
        source, spec, seed=config.seed, augment=augment if augment.enabled else None, events=events
    )


def validation_windows(config: TrainConfig) -> list[Window]:
    """Fixed validation windows: the ``val`` split, or simulated sequences in online mode."""
    clock = Clock.parse(config.clock)
    if config.data:
        windows = fixed_windows(config.data, "val", config.window_ms, clock)
    else:
        simulate = online_simulator(config, split="val")
        windows = []
        for i in range(config.val_sequences):
            rec, name = simulate(i), f"online-val:{i}"
            windows += (
                sequence_windows(rec, config.window_ms, name)
                if clock.is_paper
                else clocked_sequence_windows(rec, config.window_ms, clock, name)
            )
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
    # on the event clock, outputs and labels are rotations per step: scored in rad/s
    rates = np.stack([w.rates for w in windows])[:, :, None]
    prediction = prediction * rates
    truth = np.stack([w.omega for w in windows]) * rates
    return validation_metrics(prediction, truth, config.loss_start_step)


def resolve_compute(config: TrainConfig, ctx: distributed.DistContext) -> str:
    """ "sparse" or "dense": how this run computes its training steps (see ``TrainConfig``)."""
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
        if compute == "sparse":
            # The engine's threads own the cores. Torch's own ops (readout, loss, Adam) are
            # small, and after each parallel one its OpenMP workers spin on those cores.
            torch.set_num_threads(1)
    return compute


def seed_everything(seed: int) -> None:
    """Seed the global generators (model init); samples use their own per-index generators."""
    random.seed(seed)
    torch.manual_seed(seed)


RUN_FIXED = ("model", "input", "model_kwargs", "freeze", "learn_tau")
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

    On a CPU it has glibc's malloc keep freed memory for the rest of the process
    (:func:`spikegyro.train.memory.keep_freed_memory`), so that a step's activations are not
    mapped and zeroed anew every step.

    Args:
        config: the resolved configuration (``config.out`` is the run directory).
        resume: continue from ``out/last.pt`` + ``out/resume.pt`` (must exist).
        progress: show a progress bar on rank 0.
    """
    if not config.out:
        raise InputError("train: give a run directory (--out DIR).")
    ctx = distributed.init_distributed(config.device)
    config = replace(config, amp=resolve_amp(config.amp, config.input, ctx.device))
    try:
        return _train(config, ctx, resume=resume, progress=progress)
    finally:
        distributed.shutdown(ctx)


@dataclass
class _Run:
    """The parts of one run, built before its first step and shared by every step."""

    config: TrainConfig
    ctx: distributed.DistContext
    files: RunFiles
    spec: InputSpec
    kwargs: dict[str, Any]  # the model's constructor arguments, saved with each checkpoint
    model: nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: Any
    compute: str
    before: dict[str, float]  # the training behind the weights the run started from (--init)
    start_step: int = 0
    elapsed0: float = 0.0  # seconds trained before this process started (resume)
    best: float = math.inf  # lowest validation median relative error so far
    best_on: str = ""  # windows_fingerprint of the validation windows ``best`` was measured on
    best_step: int = 0  # the step ``best`` was measured at
    val_windows: list[Window] = field(default_factory=list)
    real: RealWindows | None = None  # unlabeled real windows (``config.real``)
    real_val: RealValidation | None = None  # the held-out real windows, scored


@dataclass
class _Progress:
    """Where the loop stands: step, clock, the loss since the last log row, last metrics."""

    step: int
    t0: float  # monotonic time at which the run (resumed time included) started
    loss_sum: float = 0.0
    loss_n: int = 0
    real_sum: float = 0.0  # the real windows' loss (weighted), since the last log row
    real_n: int = 0
    last_loss: float = math.nan
    val: dict[str, float] = field(default_factory=dict)
    stopped_early: bool = False
    out_of_patience: bool = False  # the last validation's verdict under --patience
    batch: tuple[Any, Any] | None = None  # the last batch on the device, for the bare step


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
    if ctx.device.type == "cpu":
        keep_freed_memory()
    run = _build_run(config, ctx, resume)
    net: nn.Module = run.model
    if ctx.distributed:
        ids = [ctx.device.index] if ctx.device.type == "cuda" else None
        net = DistributedDataParallel(run.model, device_ids=ids)
    events = events_on_device(ctx.device, config.data_path, run.compute == "sparse")
    samples = None if config.real_only else training_samples(config, run.spec, events=events)
    _prepare_validation(run)
    if ctx.is_main:
        run.files.write_config(config)
        run.files.start_log(run.start_step)
    writer = tensorboard(run.files.dir) if config.tensorboard and ctx.is_main else None
    val_start = _validate_start(run, writer)
    loader = None if samples is None else _loader(samples, config, ctx, run.start_step)
    bar = ProgressBar(config, run.start_step, enabled=progress and ctx.is_main)
    clock = RunClock(config.batch_size)
    state = _Progress(step=run.start_step, t0=time.monotonic() - run.elapsed0)
    with bar, GracefulStop() as interrupt:
        _steps(run, net, loader, state, clock, bar, writer, interrupt)
    elapsed = time.monotonic() - state.t0
    bare = None
    # the bare step times the supervised step on a batch of labelled windows only
    if (
        config.bare_steps
        and state.step > run.start_step
        and not interrupt.requested
        and not config.real
    ):
        bare = _bare_step(run, state)
    data_path = "events" if events else "dense"
    if ctx.is_main:
        if writer is not None:
            writer.close()
        run.files.plot_curve()
        run.files.write_throughput(clock.samples_per_s, bare, data_path, ctx.world_size)
    return TrainResult(run.files.dir, state.step, elapsed, state.last_loss, run.best, state.val,
                       state.stopped_early, clock.samples_per_s, bare, data_path,
                       interrupt.requested and state.stopped_early, run.compute,
                       val_start, run.best_step, state.out_of_patience)  # fmt: skip


def _build_run(config: TrainConfig, ctx: distributed.DistContext, resume: bool) -> _Run:
    """Model, optimizer and schedule, from ``--init`` or, on resume, from the run's state."""
    spec = input_spec_of(config)
    real = real_windows(config, spec)  # first: a bad recording must stop the run before it starts
    kwargs = model_kwargs_of(config, spec)
    seed_everything(config.seed)
    model = build_model(config.model, **kwargs)
    before = load_init(model, config) if config.init and not resume else {}
    model = model.to(ctx.device)
    compute = configure_compute(model, config, ctx)
    trained = model.freeze(config.freeze) if config.freeze else list(model.parameters())
    optimizer = torch.optim.Adam(trained, lr=config.lr)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: lr_factor(s, config))
    run = _Run(config, ctx, RunFiles(Path(config.out)), spec, kwargs, model, optimizer, scheduler,
               compute, before, real=real)  # fmt: skip
    if resume:
        resumed = load_resume(run.files, model, optimizer, scheduler, ctx.device)
        run.start_step, run.best, run.elapsed0, run.best_on, run.before, run.best_step = resumed
        _use_configured_lr(optimizer, scheduler, config)
        check_time_budget(config.max_minutes, run.elapsed0)
    return run


def real_windows(config: TrainConfig, spec: InputSpec) -> RealWindows | None:
    """The run's unlabeled real training windows (None without ``config.real``), the
    recordings read and checked."""
    if not config.real:
        return None
    window_ms = max(config.window_ms, config.train_window_ms)
    loss = ContrastLossConfig(span_ms=config.real_span_ms, from_step=config.train_loss_start_step)
    recordings = load_recordings(config.real, config.real_calib or [], window_ms,
                                 config.real_holdout, loss,
                                 span_s=(config.real_start, config.real_end))  # fmt: skip
    return RealWindows(recordings, replace(spec, window_ms=config.train_window_ms), loss,
                       config.seed)  # fmt: skip


def _validate_start(run: _Run, writer: Any) -> dict[str, float]:
    """Score the starting weights on the held-out real windows (a log row at step 0), so that
    what the run gains on real data is measured; {} without real recordings or on resume."""
    if run.real_val is None or run.start_step or not run.ctx.is_main:
        return {}
    val = run.real_val.score(run.model)
    _write_row(run.files, writer, {"step": 0, **{k: f"{v:.6g}" for k, v in val.items()}})
    return val


def _use_configured_lr(
    optimizer: torch.optim.Optimizer, scheduler: Any, config: TrainConfig
) -> None:
    """Put a resumed optimizer and schedule on the configuration's learning rate: their saved
    state holds the rate the run was started with, which ``--lr`` on ``--resume`` overrides."""
    scheduler.base_lrs = [config.lr] * len(optimizer.param_groups)
    for group in optimizer.param_groups:
        group["initial_lr"] = config.lr
        group["lr"] = config.lr * lr_factor(scheduler.last_epoch, config)


def _prepare_validation(run: _Run) -> None:
    """Load the validation windows on rank 0; forget a resumed best measured on other data."""
    if not run.ctx.is_main:
        return
    if run.real is not None:
        loss = replace(run.real.loss, from_step=run.config.loss_start_step)
        spec = replace(run.real.spec, window_ms=run.config.window_ms)
        run.real_val = RealValidation(RealWindows(run.real.recordings, spec, loss, run.config.seed))
    run.val_windows = [] if run.config.real_only else validation_windows(run.config)
    real_windows = run.real_val.windows if run.real_val is not None else []
    val_id = windows_fingerprint(run.val_windows + real_windows)
    if run.best_on != val_id and math.isfinite(run.best):
        # A best score on other validation data must not block the new data's best.pt.
        print(
            f"validation data differ from the resumed run's: best {run.best:.4f} forgotten",
            file=sys.stderr,
        )
        run.best, run.best_step = math.inf, run.start_step
    run.best_on = val_id


def _data_workers(requested: int) -> int:
    """DataLoader worker processes for ``requested``: at most the cores this process may run on,
    since more only contend for them (the presets ask for 4, for GPU hosts)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return min(requested, cores or 1)


def _loader(
    samples: TrainingSamples, config: TrainConfig, ctx: distributed.DistContext, start_step: int
) -> DataLoader:
    """This process's share of the batches of steps ``start_step .. iterations-1``."""
    workers = _data_workers(config.num_workers)
    batch = config.batch_size - config.real_count()  # the simulated windows of each step
    return DataLoader(
        samples,
        batch_size=batch // ctx.world_size,
        sampler=StepSampler(start_step, config.iterations, batch, ctx.rank, ctx.world_size),
        num_workers=workers,
        collate_fn=samples.collate,
        worker_init_fn=_worker_init if workers else None,
        persistent_workers=False,
        pin_memory=ctx.device.type == "cuda",
    )


def _batches(run: _Run, loader: DataLoader | None, events: bool) -> Iterator[tuple[Any, ...]]:
    """Each step's (inputs, targets, real windows' sub-windows): the simulated windows of the
    loader first, then ``config.real_count()`` real ones drawn for the step."""
    config = run.config
    steps = range(run.start_step, config.iterations)
    if run.real is None:
        assert loader is not None
        for inputs, targets in loader:
            yield inputs, targets, []
        return
    spec = run.real.spec
    empty = torch.empty(0, 3, spec.window_ms)
    sim = loader if loader is not None else ((None, empty) for _ in steps)
    for step, (inputs, targets) in zip(steps, sim, strict=False):
        drawn = run.real.draw(step, config.real_count())
        real = model_inputs([w for w, _ in drawn], spec, events)
        if inputs is not None:
            real = EventBatch.concatenate([inputs, real]) if events else torch.cat([inputs, real])
        yield real, targets, [subs for _, subs in drawn]


def _steps(
    run: _Run,
    net: nn.Module,
    loader: DataLoader | None,
    state: _Progress,
    clock: RunClock,
    bar: ProgressBar,
    writer: Any,
    interrupt: GracefulStop,
) -> None:
    """Train until the last iteration, the time budget or Ctrl-C, logging, validating and
    checkpointing on the way (every process agrees on when to stop)."""
    config, ctx = run.config, run.ctx
    amp = config.amp != "off"
    spec = replace(run.spec, window_ms=config.train_window_ms)
    events = loader.dataset.events if loader is not None else run.compute == "sparse"
    net.train()
    for inputs, targets, subs in _batches(run, loader, events):
        x, y = device_batch(inputs, targets, spec, ctx.device, run.compute == "sparse")
        extra = _real_loss(run, subs, state) if subs else None
        loss = train_step(net, run.optimizer, x, y, config.train_loss_start_step,
                          config.grad_clip, amp, extra)  # fmt: skip
        run.scheduler.step()
        state.batch = (x, y)
        state.step += 1
        state.loss_sum += float(loss)
        state.loss_n += 1
        clock.step()
        over_time = config.max_minutes > 0 and time.monotonic() - state.t0 > 60 * config.max_minutes
        stop = distributed.agree(over_time or interrupt.requested, ctx)
        final = stop or state.step == config.iterations
        row = _log_row(run, state) if state.step % config.log_every == 0 or final else {}
        if state.step % config.val_every == 0 or final:
            with clock.paused():
                row.update(_validate_and_checkpoint(run, state))
            state.out_of_patience = distributed.agree(_out_of_patience(run, state.step), ctx)
            stop = stop or state.out_of_patience
        if row and ctx.is_main:
            _write_row(run.files, writer, {"step": state.step, **row})
        bar.update(state.step, state.last_loss, state.val)
        if stop:
            state.stopped_early = state.step < config.iterations
            break


def _out_of_patience(run: _Run, step: int) -> bool:
    """Whether ``patience`` validations in a row, up to ``step``, have not improved the best."""
    patience = run.config.patience
    return patience > 0 and step - run.best_step >= patience * run.config.val_every


def _real_loss(run: _Run, subs: list[Any], state: _Progress) -> Any:
    """The self-supervised loss of a step's real windows, as a function of their outputs; its
    value is added to the log row's ``real_loss``."""
    assert run.real is not None
    config = run.config

    def loss(omega: Any) -> Any:
        value = config.real_weight * batch_loss(omega, subs, run.real.loss, config.real_loss)
        state.real_sum += float(value.detach())
        state.real_n += 1
        return value

    return loss


def _log_row(run: _Run, state: _Progress) -> dict[str, Any]:
    """The loss (averaged over processes) and rates since the last row; restarts the average."""
    state.last_loss = distributed.mean_across(state.loss_sum / state.loss_n, run.ctx)
    state.loss_sum, state.loss_n = 0.0, 0
    real = math.nan
    if run.real is not None:  # on every process alike: the mean is a collective call
        local = state.real_sum / state.real_n if state.real_n else math.nan
        real = distributed.mean_across(local, run.ctx)
        state.real_sum, state.real_n = 0.0, 0
    elapsed = time.monotonic() - state.t0
    rate = (state.step - run.start_step) * run.config.batch_size / max(elapsed - run.elapsed0, 1e-9)
    return {
        "step": state.step,
        "loss": f"{state.last_loss:.6g}",
        "real_loss": "" if math.isnan(real) else f"{real:.6g}",
        "lr": f"{run.scheduler.get_last_lr()[0]:.6g}",
        "elapsed_s": f"{elapsed:.1f}",
        "samples_per_s": f"{rate:.2f}",
    }


def _validate_and_checkpoint(run: _Run, state: _Progress) -> dict[str, str]:
    """Validate and checkpoint on rank 0 (the others wait); returns the metrics' log columns."""
    columns = {}
    if run.ctx.is_main:
        state.val = {}
        if run.val_windows:
            state.val = validate(run.model, run.spec, run.val_windows, run.config, run.ctx.device)
        if run.real_val is not None:
            state.val.update(run.real_val.score(run.model))
        columns = {k: f"{v:.6g}" for k, v in state.val.items()}
        score = selection_score(state.val)
        better = score < run.best
        run.best = min(run.best, score)
        if better:
            run.best_step = state.step
        _checkpoint(run, state.step, time.monotonic() - state.t0, state.val, better)
    distributed.barrier(run.ctx)
    return columns


def selection_score(val: dict[str, float]) -> float:
    """What best.pt minimizes: with real recordings, the held-out real windows' contrast gain
    (negated: the run is for real cameras), else the validation median relative error."""
    if "val_real_gain" in val:
        return -val["val_real_gain"]
    return val["val_median_rel"]


def _write_row(files: RunFiles, writer: Any, row: dict[str, Any]) -> None:
    """Append a row to log.csv and, with --tensorboard, its numbers to the scalars."""
    files.append_log(row)
    if writer is not None:
        for k, v in row.items():
            if k != "step" and v != "":
                writer.add_scalar(k, float(v), row["step"])


def _bare_step(run: _Run, state: _Progress) -> BareStep:
    """Time bare steps on the last batch, to compare with the run's samples/s."""
    config = run.config
    assert state.batch is not None  # the run has taken a step
    x, y = state.batch
    return bare_step_rate(
        run.model, x, y, windows=config.batch_size // run.ctx.world_size, lr=config.lr,
        loss_start_step=config.train_loss_start_step, grad_clip=config.grad_clip,
        steps=config.bare_steps, amp=config.amp != "off",
    )  # fmt: skip


def _checkpoint(
    run: _Run, step: int, elapsed_s: float, val: dict[str, float], better: bool
) -> None:
    """Write last.pt (and best.pt when ``better``) and resume.pt, which keeps the best score
    and the fingerprint of the validation windows it was measured on."""
    config = run.config
    extra = {"config": config.as_dict(), "step": step, "metrics": val, "elapsed_s": elapsed_s,
             "before": run.before}  # fmt: skip
    save = functools.partial(
        save_checkpoint, model=run.model, name=config.model, model_kwargs=run.kwargs,
        input_spec=run.spec.as_dict(), extra=extra,
    )  # fmt: skip
    save(run.files.last)
    if better:
        save(run.files.best)
    state = {
        "step": step,
        "best": run.best,
        "best_on": run.best_on,
        "best_step": run.best_step,
        "elapsed_s": elapsed_s,
        "optimizer": run.optimizer.state_dict(),
        "scheduler": run.scheduler.state_dict(),
        "rng": rng_states(),
    }
    with atomic_path(run.files.resume) as tmp:
        torch.save(state, tmp)
