"""Do accumulated frames generalize like voxel grids? (docs/analysis.md).

Trains ANN-6 on every 20 ms window of a dataset's train split, once on accumulated frames and
once on voxel grids (same network, windows, batches and steps), and prints the median relative
error of each on its training windows and on the held-out windows of the val and test splits,
with the sign of ω (the paper's metric) and without it (min(‖ω̂ − ω‖, ‖ω̂ + ω‖) / ‖ω‖: a
network that knows the axis and speed but not the direction scores well here).

A frame is the same for (scene, ω) and for the contrast-inverted scene turning at −ω, and an
edge crossing a pixel fires the same number of events at any speed: a frame network must learn
both direction and speed from the scene's look, which voxel grids give it through time.

    python scripts/analysis/frames_vs_voxel.py --data DIR [--steps 400] [--scale 0.5]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from spikegyro.events.io import read_recording
from spikegyro.models.registry import build_model
from spikegyro.train.data import (
    InputSpec,
    encode_target,
    encode_window,
    sequence_windows,
    split_files,
)
from spikegyro.train.loss import angular_velocity_loss

WINDOW_MS = 20
TRAIN_SCORED = 200
"""Training windows scored at each report (the first ones; scoring all would cost a step's time
many times over)."""


def load(data: str, splits: tuple[str, ...], spec: InputSpec) -> tuple[torch.Tensor, ...]:
    """Inputs and mean-ω targets (rad/s) of every 20 ms window of ``splits``."""
    windows = [
        w
        for split in splits
        for path in split_files(data, split)
        for w in sequence_windows(read_recording(path), WINDOW_MS)
    ]
    inputs = torch.cat([encode_window(w, spec) for w in windows])
    return inputs, torch.cat([encode_target(w, spec) for w in windows])


def errors(model: torch.nn.Module, inputs: torch.Tensor, omega: torch.Tensor) -> tuple:
    """(median relative error, the same without the sign of ω), the model in eval mode."""
    model.eval()
    with torch.no_grad():
        pred = model(inputs)
    model.train()
    speed = omega.norm(dim=1)
    signed = (pred - omega).norm(dim=1) / speed
    unsigned = torch.minimum((pred - omega).norm(dim=1), (pred + omega).norm(dim=1)) / speed
    return float(signed.median()), float(unsigned.median())


def run(args: argparse.Namespace, representation: str) -> None:
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    spec = InputSpec.for_representation(
        representation, sensor=(240, 180), scale=args.scale, window_ms=WINDOW_MS,
        target_ms=WINDOW_MS,
    )  # fmt: skip
    train_x, train_y = load(args.data, ("train",), spec)
    held_x, held_y = load(args.data, ("val", "test"), spec)
    model = build_model("ann6", in_channels=spec.in_channels)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    for step in range(args.steps + 1):
        if step % args.report_every == 0:
            seen = errors(model, train_x[:TRAIN_SCORED], train_y[:TRAIN_SCORED])
            held = errors(model, held_x, held_y)
            print(
                f"{representation:6s} step {step:5d}  train {seen[0]:.3f} / {seen[1]:.3f}"
                f"  held-out {held[0]:.3f} / {held[1]:.3f}  (signed / sign-free)",
                flush=True,
            )
        if step == args.steps:
            break
        batch = torch.from_numpy(rng.choice(len(train_x), args.batch, replace=False))
        optimizer.zero_grad()
        angular_velocity_loss(model(train_x[batch]), train_y[batch]).backward()
        optimizer.step()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="dataset with train, val and test splits")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--report-every", type=int, default=100)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--scale", type=float, default=0.5, help="0.5: 240x180 -> 120x90")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.steps < 1 or args.report_every < 1 or args.batch < 1:
        parser.error("--steps, --report-every and --batch must be at least 1")
    for representation in ("frames", "voxel"):
        run(args, representation)


if __name__ == "__main__":
    main()
