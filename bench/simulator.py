"""Simulator throughput at 240x180 on the default trajectory distribution, one process, one thread.

Prints simulated seconds per CPU-second and events per CPU-second (target: >= 1.0 simulated
second per CPU-second), over dataset sequences simulated exactly as ``spikegyro simulate`` does.

    OMP_NUM_THREADS=1 python bench/simulator.py [--sequences 12] [--duration-ms 500]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import time

import numpy as np
import torch

from spikegyro.sim.dataset import SimConfig, simulate_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=12)
    parser.add_argument("--duration-ms", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = SimConfig(duration_ms=args.duration_ms)
    simulate_sequence(SimConfig(duration_ms=100), 0, seed=args.seed + 1)  # warm-up (imports)
    rows = []
    for i in range(args.sequences):
        c0, w0 = time.process_time(), time.perf_counter()
        rec = simulate_sequence(config, i, seed=args.seed)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        speed = np.degrees(np.linalg.norm(rec.gyro.omega, axis=1)).mean()
        rows.append((cpu, wall, len(rec.events), speed, rec.attrs["frames"]))
        print(
            f"seq {i:3d}  |w| {speed:6.0f} deg/s  frames {rec.attrs['frames']:5d}  "
            f"events {len(rec.events):9,d}  cpu {cpu:6.2f} s  wall {wall:6.2f} s  "
            f"{rec.attrs['scene']}"
        )
    cpu, wall, events, speed, frames = (np.array(c, dtype=float) for c in zip(*rows, strict=True))
    sim_s = args.sequences * args.duration_ms / 1000
    print(
        f"\n{args.sequences} sequences x {args.duration_ms} ms at 240x180, mean |w| "
        f"{speed.mean():.0f} deg/s, {frames.mean():.0f} frames/sequence, "
        f"{events.sum() / sim_s / 1e6:.2f} Mev per simulated second"
    )
    print(f"simulated seconds per CPU-second: {sim_s / cpu.sum():.2f}")
    print(f"simulated seconds per wall-second: {sim_s / wall.sum():.2f}")
    print(f"events per CPU-second: {events.sum() / cpu.sum() / 1e6:.2f} M")


if __name__ == "__main__":
    main()
