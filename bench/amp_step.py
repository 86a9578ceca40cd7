"""Bare ANN training step in float32 against bfloat16 autocast (``spikegyro train --amp``), and
against the other speed-ups a CPU or GPU might take: channels-last memory and torch.compile.

The step is the trainer's own (:func:`spikegyro.train.throughput.train_step`: the forward pass
under ``torch.autocast(bfloat16)`` when amp is on, the loss, the backward pass and Adam in
float32) on a registry model built with the input channels ``train`` gives it. One batch of B
windows x 5 sub-windows of 20 ms at 240x180, flattened into B x 5 images as ``train`` does,
already on the device: sparse random planes (5 % of the pixels hold a value). For each model,
input and batch, every variant (``--variants``: float32, bf16, bf16+cl (channels-last),
bf16+compile, float32+cl, ...) in the same run, their steps taken in turn (one step of each,
then the next round), so that a load that changes during the run weighs on all alike: median
and mean ms of ``--repeats`` steps after ``--warmup``, windows (100 ms samples) per second and the
ratio to the first variant; and the median CPU time of a step (all threads of this process),
which a CPU that other processes share bounds better than wall time. The trainer's
defaults are kept (cuDNN's TF32 convolutions on, ``cudnn.benchmark`` off), so "float32" means
what ``train --amp off`` runs.

    python bench/amp_step.py --device cpu --batches 16 --variants float32 bf16 bf16+cl
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from spikegyro.models.registry import build_model
from spikegyro.train.data import InputSpec
from spikegyro.train.throughput import synchronize, train_step

SUB_WINDOWS = 5
OPTIONS = ("cl", "compile")


def parse_variant(text: str) -> tuple[bool, set[str]]:
    """'bf16+cl' -> (amp on, {"cl"}); the first part is the precision, float32 or bf16."""
    precision, *options = text.split("+")
    if precision not in ("float32", "bf16") or not set(options) <= set(OPTIONS):
        raise SystemExit(f"--variants {text}: float32 or bf16, then +cl and/or +compile")
    return precision == "bf16", set(options)


def make_step(name: str, representation: str, windows: int, variant: str, args):
    """A closure taking one training step of the variant, on its own model copy and batch."""
    amp, options = parse_variant(variant)
    device = torch.device(args.device)
    spec = InputSpec(representation=representation, output="window_mean", window_ms=100,
                     target_ms=100 // SUB_WINDOWS, num_bins=5)  # fmt: skip
    torch.manual_seed(0)
    net = build_model(name, in_channels=spec.in_channels).to(device).train()
    images = windows * SUB_WINDOWS
    generator = torch.Generator().manual_seed(1)
    x = torch.randn(images, spec.in_channels, args.height, args.width, generator=generator)
    x = (x * (torch.rand(x.shape, generator=generator) < 0.05)).to(device)
    y = torch.randn(images, 3, generator=generator).to(device)
    if "cl" in options:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
    model = torch.compile(net) if "compile" in options else net
    return lambda: train_step(model, optimizer, x, y, 0, 0.0, amp)


def measure(name: str, representation: str, windows: int, args) -> list[dict]:
    """Every variant's step times for one model, input and batch, taken round-robin."""
    device = torch.device(args.device)
    steps = {v: make_step(name, representation, windows, v, args) for v in args.variants}
    times: dict[str, list[float]] = {v: [] for v in args.variants}
    cpu: dict[str, list[float]] = {v: [] for v in args.variants}
    for step in steps.values():  # warm-up (and compilation) before any timing
        for _ in range(args.warmup):
            step()
    for _ in range(args.repeats):
        for v, step in steps.items():
            synchronize(device)
            start, start_cpu = time.perf_counter(), time.process_time()
            step()
            synchronize(device)
            times[v].append(time.perf_counter() - start)
            cpu[v].append(time.process_time() - start_cpu)
    rows = []
    for v in args.variants:
        median = statistics.median(times[v])
        rows.append({"model": name, "input": representation, "windows": windows,
                     "images": windows * SUB_WINDOWS, "variant": v, "median_ms": 1000 * median,
                     "mean_ms": 1000 * statistics.fmean(times[v]),
                     "windows_per_s": windows / median,
                     "cpu_ms": 1000 * statistics.median(cpu[v])})  # fmt: skip
    return rows


def table_row(row: dict, base: dict) -> str:
    return (
        f"| {row['model']} | {row['input']} | {row['windows']} ({row['images']}) | "
        f"{row['variant']} | {row['median_ms']:.1f} ({row['mean_ms']:.1f}) | "
        f"{row['windows_per_s']:.1f} | {base['median_ms'] / row['median_ms']:.2f}x | "
        f"{row['cpu_ms']:.0f} | {base['cpu_ms'] / row['cpu_ms']:.2f}x |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--batches", type=int, nargs="+", default=[2, 16], help="windows")
    parser.add_argument("--models", nargs="+", help="MODEL:INPUT pairs",
                        default=["ann6:voxel", "resnet50:voxel", "resnet50:frames"])  # fmt: skip
    parser.add_argument("--variants", nargs="+", default=["float32", "bf16"],
                        help="float32 or bf16, then +cl (channels-last), +compile")  # fmt: skip
    parser.add_argument("--width", type=int, default=240)
    parser.add_argument("--height", type=int, default=180)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    args = parser.parse_args()
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "CPU"
    print(
        f"torch {torch.__version__}, {name}, {torch.get_num_threads()} threads, "
        f"{args.width}x{args.height}, {SUB_WINDOWS} sub-windows per window, median (mean) of "
        f"{args.repeats} steps after {args.warmup}, variants in turn; x: against {args.variants[0]}"
    )
    print("| model | input | windows (images) | variant | ms per step | windows/s | x | CPU ms "
          "per step | x (CPU) |\n|---|---|---:|---|---:|---:|---:|---:|---:|")  # fmt: skip
    results = []
    for pair in args.models:
        model, representation = pair.split(":")
        for windows in args.batches:
            rows = measure(model, representation, windows, args)
            results += rows
            for row in rows:
                print(table_row(row, rows[0]), flush=True)
            if device.type == "cuda":
                torch.cuda.empty_cache()
    if args.json:
        args.json.write_text(json.dumps({"device": name, "rows": results}, indent=2) + "\n")


if __name__ == "__main__":
    main()
