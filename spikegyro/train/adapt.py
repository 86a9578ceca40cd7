"""Adapting bundled weights to a user's own camera from its recordings alone, without a gyro.

A run of the training loop with real windows only (``real_share`` 1) and the self-supervised
contrast loss (:mod:`spikegyro.train.selfsup`), from the bundled weights (or any checkpoint),
under a time budget. The weights that score the highest contrast gain on the recordings'
held-out tails are written to the output checkpoint; when no validation beats the starting
weights, those are written instead, and the result says so.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from spikegyro.errors import InputError
from spikegyro.events.clock import Clock
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import read_checkpoint
from spikegyro.pretrained import resolve_checkpoint
from spikegyro.train.loop import TrainResult, train
from spikegyro.train.presets import TrainConfig, resolve_config

SNN_MODELS = ("snn6", "snn6-grid")
"""The networks ``adapt`` takes: those with a per-millisecond output."""


@dataclass(frozen=True)
class AdaptSettings:
    """What ``spikegyro adapt`` trains (see :class:`~spikegyro.train.presets.TrainConfig` for
    the fields it maps to).

    Attributes:
        recordings: the user's recordings (any format the project reads).
        camera: a calibration file or ``fx,fy,cx,cy`` (pixels); None: an Event Camera Dataset
            folder's calib.txt.
        checkpoint: the starting weights, a bundled name or a path.
        out: the checkpoint to write.
        start_s, end_s: the part of each recording used, seconds after its first event.
        max_minutes: wall-time budget of the training.
        loss: "contrast" or "teacher".
        lr: Adam's learning rate; batch_size: real windows per step; holdout: the last share of
            each recording held out to measure the gain on.
    """

    recordings: list[str]
    camera: str | None
    checkpoint: str
    out: Path
    start_s: float = 0.0
    end_s: float | None = None
    max_minutes: float = 10.0
    loss: str = "contrast"
    lr: float = 1e-4
    batch_size: int = 4
    holdout: float = 0.2
    seed: int = 0


def run_dir_of(out: Path) -> Path:
    """Where the adaptation's run files go: ``NAME-run/`` beside ``NAME.pt``."""
    return out.with_name(f"{out.stem}-run")


def adapt_config(settings: AdaptSettings) -> TrainConfig:
    """The training run of an adaptation, every option checked (nothing is written)."""
    out = settings.out
    if out.is_dir() or not out.parent.is_dir():
        raise InputError(
            f"--out {out}: give a checkpoint file in an existing folder (e.g. cam.pt)."
        )
    run_dir = run_dir_of(out)
    if (run_dir / "last.pt").exists():
        raise InputError(f"{run_dir}: already holds an adaptation run; choose another --out.")
    if not settings.max_minutes > 0:
        raise InputError(f"--max-minutes {settings.max_minutes}: must be > 0.")
    init = resolve_checkpoint(settings.checkpoint)
    payload = read_checkpoint(init, "--checkpoint")
    model = payload["model"]
    if model not in SNN_MODELS:
        raise InputError(
            f"--checkpoint {settings.checkpoint}: a {model} network; adapt fine-tunes the "
            f"spiking networks ({', '.join(SNN_MODELS)}), whose output is ω every millisecond."
        )
    clock = Clock.from_dict(payload.get("input", {}).get("clock"))
    return resolve_config(
        "paper",
        {
            "out": str(run_dir),
            "init": str(init),
            "model": model,
            "real": list(settings.recordings),
            "real_calib": [settings.camera] if settings.camera else None,
            "real_share": 1.0,
            "real_loss": settings.loss,
            "real_holdout": settings.holdout if clock.is_paper else max(settings.holdout, 0.3),
            "real_start": settings.start_s,
            "real_end": settings.end_s,
            "lr": settings.lr,
            "batch_size": settings.batch_size,
            "max_minutes": settings.max_minutes,
            "val_every": 50,
            "log_every": 5,
            "num_workers": 0,
            "seed": settings.seed,
            "time_reverse": 0.0,
            "hflip": 0.0,
            "vflip": 0.0,
            # the network keeps its clock; on the event clock windows count steps, which last
            # longer than 1 ms where the motion is slow: shorter windows, a longer held-out part
            "clock": clock.text,
            **({} if clock.is_paper else CLOCKED_WINDOWS),
        },
    )


CLOCKED_WINDOWS = {
    "window_ms": 50,
    "train_window_ms": 50,
    "loss_start_step": 35,
    "train_loss_start_step": 35,
}
"""Window and loss steps of an adaptation on the event clock (SNN-6 settles in about 30 steps)."""


@dataclass(frozen=True)
class Adapted:
    """An adaptation's outcome: the run, the held-out contrast gain of the starting and of the
    written weights, contrast maximization's on the same windows, and whether the written
    weights are the starting ones (no validation beat them)."""

    result: TrainResult
    gain_start: float
    gain_end: float
    gain_cmax: float
    kept_start: bool


def adapt(settings: AdaptSettings, config: TrainConfig) -> Adapted:
    """Train as ``config`` says and write the best weights to ``settings.out`` (atomically)."""
    result = train(config)
    start = result.val_start
    gain_start = start.get("val_real_gain", float("nan"))
    gain_best = -result.best_score
    kept_start = not gain_best > gain_start
    source = Path(config.init) if kept_start else Path(config.out) / "best.pt"
    with atomic_path(settings.out) as tmp:
        shutil.copyfile(source, tmp)
    return Adapted(
        result,
        gain_start,
        gain_start if kept_start else gain_best,
        start.get("val_real_gain_cmax", float("nan")),
        kept_start,
    )
