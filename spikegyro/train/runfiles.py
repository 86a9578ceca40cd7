"""The files of a run directory and the progress bar of a training run (rank 0 only).

``config.json`` (the resolved configuration), ``log.csv`` (one row per ``log_every`` steps),
``last.pt``/``best.pt`` (model checkpoints), ``resume.pt`` (optimizer, scheduler, step, RNG
states), ``throughput.json`` (samples/s of the run and of the bare step) and ``loss.png``.
"""

from __future__ import annotations

import csv
import json
import random
from pathlib import Path
from typing import Any

import torch
from torch import nn

from spikegyro.errors import InputError
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import read_checkpoint, training_before, training_total
from spikegyro.models.snn6 import SNN6, adapt_state
from spikegyro.train.presets import TrainConfig
from spikegyro.train.throughput import BareStep

LOG_FIELDS = (
    "step",
    "loss",
    "real_loss",
    "lr",
    "val_loss",
    "val_median_rel",
    "val_mean_err_deg",
    "val_real_gain",
    "val_real_gain_cmax",
    "elapsed_s",
    "samples_per_s",
)
RESUME_FILE = "resume.pt"


def check_time_budget(max_minutes: float, elapsed_s: float) -> None:
    """Refuse a resume whose ``--max-minutes`` the run has already spent.

    The budget counts the whole run, resumed time included (as ``--iterations`` counts all
    steps), so resuming a 35-minute run with ``--max-minutes 6`` would stop at once.
    """
    if 0 < max_minutes * 60 <= elapsed_s:
        spent = elapsed_s / 60
        raise InputError(
            f"--max-minutes {max_minutes:g} counts the whole run, which has trained {spent:.1f} "
            f"min already: pass {spent + max_minutes:.1f} for {max_minutes:g} more minutes."
        )


# ------------------------------------------------------------------------------- run files


class RunFiles:
    """Paths and writers of a run directory (used by rank 0 only)."""

    def __init__(self, run_dir: Path) -> None:
        self.dir = run_dir
        self.config = run_dir / "config.json"
        self.log = run_dir / "log.csv"
        self.last = run_dir / "last.pt"
        self.best = run_dir / "best.pt"
        self.resume = run_dir / RESUME_FILE
        self.curve = run_dir / "loss.png"
        self.throughput = run_dir / "throughput.json"

    def write_config(self, config: TrainConfig) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.config) as tmp:
            tmp.write_text(config.to_json() + "\n")

    def start_log(self, keep_until_step: int) -> None:
        """Create the log, or on resume drop rows logged after the checkpoint being resumed."""
        rows = []
        if self.log.exists() and keep_until_step > 0:
            with open(self.log, newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= keep_until_step]
        with atomic_path(self.log) as tmp, open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, LOG_FIELDS)
            writer.writeheader()
            writer.writerows(rows)

    def append_log(self, row: dict[str, Any]) -> None:
        with open(self.log, "a", newline="") as f:
            csv.DictWriter(f, LOG_FIELDS).writerow({k: row.get(k, "") for k in LOG_FIELDS})

    def write_throughput(
        self, samples_per_s: float, bare: BareStep | None, data_path: str, world_size: int
    ) -> None:
        """throughput.json: samples/s of this run segment against the bare step's."""
        record: dict[str, Any] = {
            "data_path": data_path,
            "run_samples_per_s": samples_per_s,
            "processes": world_size,
        }
        if bare is not None:
            # The bare step ran on one process's share of the batch.
            record.update(
                bare_ms_per_step=bare.ms_per_step,
                bare_samples_per_s=bare.samples_per_s * world_size,
                run_over_bare=samples_per_s / (bare.samples_per_s * world_size),
            )
        with atomic_path(self.throughput) as tmp:
            tmp.write_text(json.dumps(record, indent=2) + "\n")

    def plot_curve(self) -> None:
        """loss.png: training loss and validation loss (rad/s) against the step."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        with open(self.log, newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows:
            return
        fig, ax = plt.subplots(figsize=(6, 3.5))
        train = [(int(r["step"]), float(r["loss"])) for r in rows if r["loss"]]
        val = [(int(r["step"]), float(r["val_loss"])) for r in rows if r["val_loss"]]
        if train:
            ax.plot(*zip(*train, strict=True), label="training loss", lw=1)
        if val:
            ax.plot(*zip(*val, strict=True), "o-", label="validation loss", lw=1.5)
        ax.set_xlabel("step")
        ax.set_ylabel("mean Euclidean error (rad/s)")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        with atomic_path(self.curve) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
        plt.close(fig)


def tensorboard(run_dir: Path) -> Any:
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        raise InputError(
            "--tensorboard needs the tensorboard package (pip install tensorboard); the CSV "
            "log is always written."
        ) from None
    return SummaryWriter(str(run_dir / "tensorboard"))


class ProgressBar:
    """A rich progress bar with loss, validation error, elapsed time and ETA (rank 0 only)."""

    def __init__(self, config: TrainConfig, start: int, enabled: bool) -> None:
        self.enabled = enabled
        if not enabled:
            return
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            TextColumn("[bold]train[/] {task.fields[model]}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("loss {task.fields[loss]}  val rel {task.fields[val]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
        )
        self.task = self.progress.add_task(
            "train", total=config.iterations, completed=start, model=config.model,
            loss="-", val="-",
        )  # fmt: skip

    def __enter__(self) -> ProgressBar:
        if self.enabled:
            self.progress.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self.progress.__exit__(*exc)

    def update(self, step: int, loss: float, val: dict[str, float]) -> None:
        if not self.enabled:
            return
        rel = val.get("val_median_rel")
        self.progress.update(
            self.task, completed=step, loss=f"{loss:.3f}" if loss == loss else "-",
            val="-" if rel is None else f"{rel:.3f}",
        )  # fmt: skip


def rng_states() -> dict[str, Any]:
    return {
        "python": random.getstate(),
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
    }


def set_rng_states(states: dict[str, Any]) -> None:
    random.setstate(states["python"])
    torch.set_rng_state(states["torch"])
    if states.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])


def load_resume(
    files: RunFiles, model: nn.Module, optimizer, scheduler, device: torch.device
) -> tuple[int, float, float, str, dict[str, float], int]:
    """Restore a run from last.pt and resume.pt; (step, best, elapsed s, best_on, before, the
    step of the best: the resumed step for runs saved before it was kept)."""
    if not (files.last.exists() and files.resume.exists()):
        raise InputError(f"{files.dir}: nothing to resume (needs last.pt and {RESUME_FILE}).")
    payload = torch.load(files.last, map_location=device, weights_only=False)
    model.load_state_dict(payload["state_dict"])
    state = torch.load(files.resume, map_location="cpu", weights_only=False)
    optimizer.load_state_dict(state["optimizer"])
    scheduler.load_state_dict(state["scheduler"])
    set_rng_states(state["rng"])
    best_on = str(state.get("best_on", ""))  # runs saved before fingerprints: unknown data
    step, best, elapsed = int(state["step"]), float(state["best"]), float(state["elapsed_s"])
    best_step = int(state.get("best_step", step))
    return step, best, elapsed, best_on, training_before(payload), best_step


def load_init(model: nn.Module, config: TrainConfig) -> dict[str, float]:
    """Start ``model`` from the weights of ``config.init``; returns the training behind them."""
    payload = read_checkpoint(config.init, "--init")
    state = payload["state_dict"]
    if isinstance(model, SNN6) and payload["model"] in ("snn6", "snn6-grid"):
        # another variant (grid readout, log-polar input, time constants): carry the weights over
        state = adapt_state(state, model)
    elif payload["model"] != config.model:
        raise InputError(
            f"--init {config.init}: a '{payload['model']}' checkpoint cannot start a "
            f"'{config.model}' run."
        )
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(f"--init {config.init}: weights do not fit ({exc}).") from None
    return training_total(payload)
