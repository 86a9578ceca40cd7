"""``predict`` throughput: the batched torch path (``--device``) against the exact stream.

Simulates test recordings at 240x180 (the shipped SNN-6's sensor), writes each to an HDF5 file
and runs ``predict_stream`` on it twice in the same process: with the event-driven stream (one
CPU thread, exact) and with the batched path on ``--device`` (segments of ``--segment-ms``
after ``--context-ms`` of warm-up, ``--batch`` per forward pass). Prints each path's real-time
factor (seconds of events per second of wall time, file reading included), their ratio, and how
far the batched ω is from the stream's after the first segment: median and max of |Δω| over the
median |ω|, and the median relative error against the simulator's ground truth of both.

    .venv/bin/python bench/batched_predict.py [--device cuda] [--sequences 4] [--duration-ms 15000]
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from spikegyro.events.core import GyroTrace
from spikegyro.events.io import write_recording
from spikegyro.metrics import median_relative_error
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.stream.batched import SegmentConfig, batched_predictor, deviation
from spikegyro.stream.model import DEFAULT_CHECKPOINT, load_streaming_model
from spikegyro.stream.predict import predict_stream
from spikegyro.stream.writer import read_predictions


def median_rel(pred: dict[str, np.ndarray], gyro: GyroTrace, skip: int) -> float:
    """The paper's median relative error of the predictions after ``skip`` steps."""
    gt = gyro.interpolate(pred["t_us"])
    return median_relative_error(pred["omega"][None], gt[None], start=skip)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="torch device of the batched path")
    parser.add_argument("--sequences", type=int, default=1)
    parser.add_argument("--duration-ms", type=int, default=2000)
    parser.add_argument("--segment-ms", type=int, default=400)
    parser.add_argument("--context-ms", type=int, default=100)
    parser.add_argument("--batch", type=int, default=None, help="default: from free memory")
    parser.add_argument("--torch-threads", type=int, default=1, help="for --device cpu")
    parser.add_argument("--checkpoint", default=str(DEFAULT_CHECKPOINT))
    parser.add_argument("--seed", type=int, default=11)
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    engine, meta = load_streaming_model(args.checkpoint)
    config = SegmentConfig(args.segment_ms, args.context_ms, args.batch)
    factory, _ = batched_predictor(args.checkpoint, args.device, config)
    spec = meta["input"]
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; {args.checkpoint}; "
          f"{args.sequences} x {args.duration_ms} ms at 240x180")  # fmt: skip
    print(f"{'seq':>3} {'events':>9} {'stream':>9} {'batched':>9} {'ratio':>7} "
          f"{'med|d|':>8} {'max|d|':>8} {'rel err stream':>14} {'batched':>8}")  # fmt: skip
    totals = np.zeros(3)  # seconds of events, stream wall, batched wall
    simulate = functools.partial(
        simulate_sequence, SimConfig(duration_ms=args.duration_ms), seed=args.seed, split="test"
    )
    with ProcessPoolExecutor(min(args.sequences, os.cpu_count() or 1)) as pool:
        recordings = list(pool.map(simulate, range(args.sequences)))  # before any timing
    with tempfile.TemporaryDirectory(prefix="bench-batched-") as tmp:
        for i, rec in enumerate(recordings):
            path = write_recording(Path(tmp) / f"rec{i}.h5", rec)
            if i == 0:  # warm-up: compiled kernels, CUDA context, allocator
                warm = (args.segment_ms + args.context_ms) / 1000
                predict_stream(path, engine, spec, Path(tmp) / "w.h5", end_s=warm)
                predict_stream(path, factory, spec, Path(tmp) / "w.h5", end_s=warm)
            runs = {}
            for name, eng in (("stream", engine), ("batched", factory)):
                out = Path(tmp) / f"{name}.h5"
                start = time.perf_counter()
                result = predict_stream(path, eng, spec, out)
                runs[name] = (time.perf_counter() - start, read_predictions(out), result)
            seconds = runs["stream"][2].steps / 1000
            wall_s, wall_b = runs["stream"][0], runs["batched"][0]
            totals += (seconds, wall_s, wall_b)
            skip = args.segment_ms
            med, worst = deviation(runs["batched"][1]["omega"], runs["stream"][1]["omega"], skip)
            print(
                f"{i:>3} {len(rec.events):>9} {seconds / wall_s:>8.2f}x {seconds / wall_b:>8.2f}x "
                f"{wall_s / wall_b:>6.2f}x {med:>8.1e} {worst:>8.1e} "
                f"{median_rel(runs['stream'][1], rec.gyro, skip):>14.3f} "
                f"{median_rel(runs['batched'][1], rec.gyro, skip):>8.3f}"
            )
    print(f"engine: {runs['batched'][2].engine}")
    print(
        f"all: stream {totals[0] / totals[1]:.2f}x real time, batched on {args.device} "
        f"{totals[0] / totals[2]:.2f}x real time; batched / stream speed "
        f"{totals[1] / totals[2]:.2f}"
    )


if __name__ == "__main__":
    main()
