"""Bare ANN training step: float32 against bfloat16 autocast (``spikegyro train --amp bf16``).

The step is the trainer's own (:func:`spikegyro.train.throughput.train_step`: the forward pass
under ``torch.autocast(bfloat16)`` when amp is on, the loss, the backward pass and Adam in
float32) on a registry model built with the input channels ``train`` gives it. One batch of B
windows x 5 sub-windows of 20 ms at 240x180, flattened into B x 5 images as ``train`` does,
already on the device: sparse random planes (5 % of the pixels hold a value). For each model,
input and batch, both precisions in the same run: median and mean ms of ``--repeats`` steps after
``--warmup``, each step timed alone with a device synchronize, their ratio and the peak device
memory of a step (CUDA only). The trainer's defaults are kept (cuDNN's TF32 convolutions on,
``cudnn.benchmark`` off), so "float32" means what ``train`` runs without ``--amp``.

    python bench/amp_step.py --device cuda [--batches 2 16] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import torch

from spikegyro.models.registry import build_model
from spikegyro.train.data import InputSpec
from spikegyro.train.throughput import timed_steps, train_step

SUB_WINDOWS = 5


def measure(name: str, representation: str, windows: int, amp: bool, args) -> dict:
    """Times of the bare step of one model, input and batch in one precision."""
    device = torch.device(args.device)
    spec = InputSpec(
        representation=representation,
        output="window_mean",
        window_ms=100,
        target_ms=100 // SUB_WINDOWS,
        num_bins=5,
    )
    torch.manual_seed(0)
    net = build_model(name, in_channels=spec.in_channels).to(device).train()
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
    images = windows * SUB_WINDOWS
    generator = torch.Generator().manual_seed(1)
    x = torch.randn(images, spec.in_channels, args.height, args.width, generator=generator)
    x = (x * (torch.rand(x.shape, generator=generator) < 0.05)).to(device)
    y = torch.randn(images, 3, generator=generator).to(device)
    times, peak = timed_steps(
        lambda: train_step(net, optimizer, x, y, 0, 0.0, amp),
        device,
        warmup=args.warmup,
        repeats=args.repeats,
    )
    return {
        "model": name,
        "input": representation,
        "windows": windows,
        "images": images,
        "amp": "bf16" if amp else "off",
        "median_ms": 1000 * statistics.median(times),
        "mean_ms": 1000 * statistics.fmean(times),
        "peak_gib": peak,
    }


def row(f32: dict, bf16: dict) -> str:
    peak = "-" if f32["peak_gib"] is None else f"{f32['peak_gib']:.2f} / {bf16['peak_gib']:.2f}"
    return (
        f"| {f32['model']} | {f32['input']} | {f32['windows']} ({f32['images']}) | "
        f"{f32['median_ms']:.1f} ({f32['mean_ms']:.1f}) | {bf16['median_ms']:.1f} "
        f"({bf16['mean_ms']:.1f}) | {f32['median_ms'] / bf16['median_ms']:.2f}x | {peak} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--batches", type=int, nargs="+", default=[2, 16], help="windows")
    parser.add_argument(
        "--models",
        nargs="+",
        help="MODEL:INPUT pairs",
        default=["ann6:voxel", "resnet50:voxel", "resnet50:frames"],
    )
    parser.add_argument("--width", type=int, default=240)
    parser.add_argument("--height", type=int, default=180)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    args = parser.parse_args()
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "CPU"
    print(
        f"torch {torch.__version__}, {name}, {args.width}x{args.height}, {SUB_WINDOWS} "
        f"sub-windows per window, median (mean) of {args.repeats} steps after {args.warmup}"
    )
    print(
        "| model | input | windows (images) | float32 ms | bf16 ms | float32 / bf16 "
        "| peak GiB float32 / bf16 |\n|---|---|---:|---:|---:|---:|---:|"
    )
    results = []
    for pair in args.models:
        model, representation = pair.split(":")
        for windows in args.batches:
            f32, bf16 = (
                measure(model, representation, windows, amp, args) for amp in (False, True)
            )
            results += [f32, bf16]
            print(row(f32, bf16), flush=True)
            if device.type == "cuda":
                torch.cuda.empty_cache()
    if args.json:
        args.json.write_text(json.dumps({"device": name, "rows": results}, indent=2) + "\n")


if __name__ == "__main__":
    main()
