"""Training in segments: one run continued over many time-limited jobs, with one joined log.

A run trained in segments (Slurm jobs with a time limit, spot instances, shared machines) is a
``spikegyro train`` run directory continued with ``--resume``; each segment ends at its
``--max-minutes`` budget with a checkpoint. ``spikegyro relay-log RUN --relay DIR`` then folds
the segment's new rows of ``RUN/log.csv`` into ``DIR/relay_log.csv`` (every segment's rows, with
a ``segment`` column, steps and elapsed seconds counted from the first segment), records the
segment in ``DIR/relay.json`` and redraws ``DIR/relay_curve.png``. ``DIR`` may be the run
directory itself (the default). When it is another folder, the run's resume state (``last.pt``,
``resume.pt``, ``config.json``, ``log.csv``) is copied there too, so that the folder can be
copied onto the next machine and resumed.

``relay.json`` keeps the offsets between the run's own counters and the joined log's (a run
started with ``--init`` from an earlier checkpoint counts from 0 again) and one entry per
segment. ``scripts/train_segments.sh`` in the repository runs one segment and folds it in; the
documentation's training page ("Training on time-limited machines") describes the workflow.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from spikegyro.errors import InputError
from spikegyro.events.io import atomic_path
from spikegyro.train.runfiles import LOG_FIELDS

RELAY_FIELDS = ("segment", *LOG_FIELDS)
STATE_FILES = ("last.pt", "resume.pt", "config.json", "log.csv")


@dataclass
class RelayState:
    """``relay.json``: relay step = run step + ``step_offset``; likewise for elapsed seconds.

    ``last_run_step`` is the run step of the newest row already in the relay.
    """

    step_offset: int = 0
    elapsed_offset_s: float = 0.0
    last_run_step: int = 0
    segments: list[dict[str, Any]] = field(default_factory=list)


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        raise InputError(f"{path}: no such log file.")
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def read_state(relay_dir: str | Path) -> RelayState:
    """The relay's offsets and segments (an empty relay when ``relay.json`` is absent)."""
    path = Path(relay_dir) / "relay.json"
    if not path.exists():
        return RelayState()
    state = RelayState(**json.loads(path.read_text()))
    # Files written before CPU runs were relayed named a segment's seconds "gpu_s".
    state.segments = [
        {("train_s" if key == "gpu_s" else key): value for key, value in entry.items()}
        for entry in state.segments
    ]
    return state


def append_segment(run_dir: str | Path, relay_dir: str | Path, note: str = "") -> dict[str, Any]:
    """Append the rows of ``run_dir/log.csv`` newer than the relay's to ``relay_log.csv``.

    Steps and elapsed seconds are shifted onto the relay's clock. Returns the new segment's
    entry (also recorded in ``relay.json``): its number, first and last relay step, and the
    seconds it trained (wall clock, on whatever machine ran it).
    """
    run_dir, relay_dir = Path(run_dir), Path(relay_dir)
    state = read_state(relay_dir)
    rows = [r for r in _read_csv(run_dir / "log.csv") if int(r["step"]) > state.last_run_step]
    if not rows:
        raise InputError(f"{run_dir / 'log.csv'}: no rows after run step {state.last_run_step}.")
    relay_csv = relay_dir / "relay_log.csv"
    old = _read_csv(relay_csv) if relay_csv.exists() else []
    segment = 1 + max((int(r["segment"]) for r in old), default=0)
    new = [
        {
            **{k: r.get(k, "") for k in RELAY_FIELDS},
            "segment": str(segment),
            "step": str(int(r["step"]) + state.step_offset),
            "elapsed_s": f"{float(r['elapsed_s']) + state.elapsed_offset_s:.1f}",
        }
        for r in rows
    ]
    first_elapsed = float(old[-1]["elapsed_s"]) if old else 0.0
    entry = {
        "segment": segment,
        "first_step": int(new[0]["step"]),
        "last_step": int(new[-1]["step"]),
        "train_s": round(float(new[-1]["elapsed_s"]) - first_elapsed, 1),
        "note": note,
    }
    relay_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(relay_csv) as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, RELAY_FIELDS)
        writer.writeheader()
        writer.writerows([*old, *new])
    state.last_run_step = int(rows[-1]["step"])
    state.segments.append(entry)
    with atomic_path(relay_dir / "relay.json") as tmp:
        tmp.write_text(json.dumps(asdict(state), indent=2) + "\n")
    return entry


def stored_minutes(run_dir: str | Path) -> float:
    """Minutes of training stored in ``run_dir/resume.pt`` (0 when the run has not started).

    ``--max-minutes`` counts them, so a segment of M more minutes passes their sum plus M.
    """
    path = Path(run_dir) / "resume.pt"
    if not path.exists():
        return 0.0
    import torch

    state = torch.load(path, map_location="cpu", weights_only=False)
    return float(state["elapsed_s"]) / 60.0


def plot_relay(relay_csv: str | Path, out_png: str | Path) -> Path:
    """Training loss and validation median relative error against the relay's step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _read_csv(Path(relay_csv))
    fig, (ax_loss, ax_val) = plt.subplots(1, 2, figsize=(10, 3.6))
    for seg in sorted({int(r["segment"]) for r in rows}):
        part = [r for r in rows if int(r["segment"]) == seg]
        train = [(int(r["step"]), float(r["loss"])) for r in part if r["loss"]]
        ax_loss.plot(*zip(*train, strict=True), lw=0.8, color=f"C{seg % 10}")
        val = [(int(r["step"]), float(r["val_median_rel"])) for r in part if r["val_median_rel"]]
        if val:
            ax_val.plot(
                *zip(*val, strict=True), "o-", ms=3, color=f"C{seg % 10}", label=f"segment {seg}"
            )
    ax_loss.set_ylabel("training loss (mean Euclidean error, rad/s)")
    ax_val.set_ylabel("validation median relative error")
    for ax in (ax_loss, ax_val):
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    ax_val.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    out_png = Path(out_png)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return out_png
