"""Contrast-maximization throughput: windows per second at 240x180, one process, one thread.

Windows come from simulated test sequences (exactly as ``spikegyro simulate`` makes them): each
estimate uses the events of the preceding ``window_ms`` (default 30 ms), as in
``predict_windows`` and ``spikegyro baseline cmax``. Two regimes are timed on the same windows:

- cold: no warm start, so a full grid search + multi-start refinement (the first estimate of a
  stream or of an evaluation window);
- stream: estimates every ``stride_ms`` warm-started from the previous one, with the grid
  searched again every ``grid_every`` estimates (the steady state of a stream).

    .venv/bin/python bench/cmax.py [--sequences 3] [--windows 30]

Prints CPU-time and wall-time rates; CPU time is the honest figure on a shared machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import time

import numpy as np
import torch

from spikegyro.baselines.cmax import CMaxConfig, estimate_window, predict_stream, window_start
from spikegyro.sim.dataset import SimConfig, simulate_sequence


def _timed(fn, *args, **kwargs) -> tuple[object, float, float]:
    """``fn(*args, **kwargs)``, its CPU time and its wall time (seconds)."""
    c0, w0 = time.process_time(), time.perf_counter()
    result = fn(*args, **kwargs)
    return result, time.process_time() - c0, time.perf_counter() - w0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=3)
    parser.add_argument("--windows", type=int, default=30, help="Cold windows per sequence.")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = CMaxConfig()
    recs = [
        simulate_sequence(SimConfig(duration_ms=500), i, seed=args.seed, split="test")
        for i in range(args.sequences)
    ]
    estimate_window(recs[0].events.slice_time(100_000, 130_000), config=config)  # warm-up
    cold_cpu = cold_wall = 0.0
    cold_n, sizes, errors = 0, [], []
    stream_cpu = stream_wall = 0.0
    stream_n = 0
    for rec in recs:
        ev = rec.events
        ends = np.linspace(50_000, 500_000, args.windows).astype(np.int64)
        for t_end in ends:
            window = ev[window_start(ev, int(t_end), config) : int(np.searchsorted(ev.t, t_end))]
            sizes.append(len(window))
            est, cpu, wall = _timed(estimate_window, window, None, config)
            cold_cpu, cold_wall, cold_n = cold_cpu + cpu, cold_wall + wall, cold_n + 1
            truth = rec.gyro.interpolate(np.array([t_end - 15_000]))[0]
            errors.append(np.linalg.norm(est - truth) / np.linalg.norm(truth))
        (times, _), cpu, wall = _timed(
            predict_stream, ev, None, config, t_first_us=30_000, t_end_us=500_000
        )
        stream_cpu, stream_wall = stream_cpu + cpu, stream_wall + wall
        stream_n += len(times)
    sizes_a = np.array(sizes)
    print(
        f"windows: {config.window_ms:.0f} ms, events per window median {np.median(sizes_a):,.0f} "
        f"(5-95 %: {np.percentile(sizes_a, 5):,.0f}-{np.percentile(sizes_a, 95):,.0f}), "
        f"subsampled to <= {config.max_events:,}"
    )
    print(
        f"cold   ({cold_n} windows, grid {config.grid_points}^3 + {config.starts} starts): "
        f"{cold_n / cold_cpu:.1f} windows per CPU-second ({cold_n / cold_wall:.1f} per wall "
        f"second); median relative error {np.median(errors):.3f}"
    )
    print(
        f"stream ({stream_n} estimates every {config.stride_ms} ms, grid every "
        f"{config.grid_every}): {stream_n / stream_cpu:.1f} windows per CPU-second "
        f"({stream_n / stream_wall:.1f} per wall second) = "
        f"{stream_n * config.stride_ms / 1000 / stream_cpu:.2f} s of events per CPU-second"
    )
    print(f"torch threads: {torch.get_num_threads()}, load average: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
