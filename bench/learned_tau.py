"""What longer time constants cost SNN-6: kernel lengths, the streaming engine, the training step.

For each factor f of ``--factors`` (default 1 2 4) an SNN-6 whose τs and τr are f times the
paper's in every spiking layer (readout 8 ms) starts from the shipped weights through
``adapt_state`` (each layer's weights scaled by the ratio of the kernels' areas, so that a steady
input rate builds the same potential and the spike rates stay comparable), its τ learned
(``SNN6(learn_tau=True)``). Measured, in one process and interleaved, so that all see the same
background load:

- the taps of ε and ν per layer (the truncation rule of :mod:`spikegyro.snn.kernels`);
- streaming (what ``predict`` runs): :class:`spikegyro.stream.stateful.StreamingSNN` on one
  thread over simulated 240x180 test sequences, the same for every f, as a real-time factor
  by wall time and by the process's CPU time (which waiting for a busy core does not count),
  and the spikes per ms of each layer (the work depends on them);
- the training step (forward + backward + Adam, ``spikegyro.train.throughput.train_step``) on the
  8 windows of ``bench/train_step.py`` (100 ms, 240x180), on the event-driven engine (2 threads,
  the cut ``train --compute sparse`` uses) and on the dense torch path (2 threads), per window:
  the paper's fixed τ, then learned τ at each f, by wall and CPU time. The median of
  ``--repeats`` steps after one warm-up step each.

Ratios are against the fixed-τ network at f = 1 measured in the same run.

    .venv/bin/python bench/learned_tau.py [--factors 1 2 4] [--repeats 3] [--dense-factors 1 4]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
from streaming import simulated_sequences  # bench/ is on the path of a script run from it
from train_step import BATCH, START, windows

from spikegyro.models.registry import PRETRAINED_SNN6, load_checkpoint
from spikegyro.models.snn6 import SNN6, adapt_state
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.stateful import StreamingSNN
from spikegyro.train.memory import keep_freed_memory
from spikegyro.train.presets import SPARSE_DEFAULT_CUT
from spikegyro.train.throughput import train_step

THREADS = 2


def network(factor: float | None) -> SNN6:
    """The shipped SNN-6 (``None``: as shipped, fixed τ), or with τ × ``factor``, learned."""
    shipped, _ = load_checkpoint(PRETRAINED_SNN6)
    if factor is None:
        return shipped
    model = SNN6(tau_scale=factor, learn_tau=True)
    model.load_state_dict(adapt_state(shipped.state_dict(), model))
    return model.eval()


def kernel_table(models: dict[str, SNN6]) -> None:
    print("taps of ε / ν per layer (readout ε)")
    for name, model in models.items():
        taps = [f"{c.srm_kernel.numel():>3}/{c.ref_kernel.numel():<3}" for c in model.convs]
        print(f"  {name:<15} " + " ".join(taps) + f"  readout {model.fc.srm_kernel.numel()}")


def streaming(models: dict[str, SNN6], sequences: list, repeats: int) -> None:
    """Real-time factor of the one-thread streaming engine over the sequences, per network, by
    wall and by CPU time (the median of ``repeats`` interleaved passes)."""
    engines = {
        name: StreamingSNN(spec_from_model(model, (2, 180, 240)), threads=1)
        for name, model in models.items()
    }
    for engine in engines.values():  # compile (or load the cache)
        engine.run(np.zeros(1, np.int64), np.array([0, 1, 1]))
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in engines}
    spikes = dict.fromkeys(engines, 0)
    lists = []
    for rec in sequences:
        ev = rec.events
        duration = int(ev.t[-1] // 1000) + 1
        index = (ev.y.astype(np.int64) * 240 + ev.x) * 2 + ev.p
        lists.append((index, np.searchsorted(ev.t // 1000, np.arange(duration + 1))))
    steps = sum(offsets.size - 1 for _, offsets in lists)
    for _ in range(repeats):
        for name, engine in engines.items():
            start, cpu = time.perf_counter(), time.process_time()
            for index, offsets in lists:
                engine.reset()
                engine.run(index, offsets)
                spikes[name] = spikes[name] + engine.spike_counts / repeats
            times[name].append((time.perf_counter() - start, time.process_time() - cpu))
    medians = {n: [statistics.median(v[k] for v in t) for k in (0, 1)] for n, t in times.items()}
    base = medians["fixed f=1"]
    print(f"streaming, 1 thread, {len(sequences)} sequences, {steps} ms in all (median of "
          f"{repeats}): real-time factor by wall and by CPU time")  # fmt: skip
    for name, (wall, cpu) in medians.items():
        rates = " ".join(f"{s / steps:7.0f}" for s in spikes[name])
        print(f"  {name:<15} {steps / 1000 / wall:6.2f}x  CPU {steps / 1000 / cpu:6.2f}x "
              f"(CPU time x{cpu / base[1]:5.2f})  spikes/ms L1..L5 {rates}")  # fmt: skip


def step_of(model: SNN6, compute: str, x, y) -> Callable[[], None]:
    model.train()
    model.set_surrogate_cut(SPARSE_DEFAULT_CUT if compute == "sparse" else 0.0)
    model.use_event_engine(THREADS if compute == "sparse" else None)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-5)
    torch_threads = 1 if compute == "sparse" else THREADS

    def step() -> None:
        torch.set_num_threads(torch_threads)
        train_step(model, optimizer, x, y, START)

    return step


def training(factors: dict[str, float | None], compute: str, inputs, y, repeats: int) -> None:
    steps = {name: step_of(network(f), compute, inputs[compute], y) for name, f in factors.items()}
    for step in steps.values():
        step()
    times: dict[str, list[tuple[float, float]]] = {n: [] for n in steps}
    for _ in range(repeats):
        for name, step in steps.items():
            start, cpu = time.perf_counter(), time.process_time()
            step()
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            times[name].append((wall / BATCH, cpu / BATCH))
    medians = {n: [statistics.median(v[k] for v in t) for k in (0, 1)] for n, t in times.items()}
    base = medians["fixed f=1"]
    print(f"training step, {compute}, {THREADS} threads, batch {BATCH}, per window (median): "
          "wall s, CPU s of the process")  # fmt: skip
    for name, (wall, cpu) in medians.items():
        print(f"  {name:<15} {wall:7.3f} s x{wall / base[0]:5.2f}   CPU {cpu:7.3f} s "
              f"x{cpu / base[1]:5.2f}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--factors", type=float, nargs="+", default=[1.0, 2.0, 4.0])
    parser.add_argument("--dense-factors", type=float, nargs="*", default=[1.0, 4.0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sequences", type=int, default=2)
    parser.add_argument("--duration-ms", type=int, default=500)
    args = parser.parse_args()
    keep_freed_memory()
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    learned = {f"learned f={f:g}": f for f in args.factors}
    models = {"fixed f=1": network(None)} | {n: network(f) for n, f in learned.items()}
    kernel_table(models)
    streaming(models, simulated_sequences(args.sequences, args.duration_ms, 0), args.repeats)
    inputs, y = windows()
    training({"fixed f=1": None, **learned}, "sparse", inputs, y, args.repeats)
    dense = {f"learned f={f:g}": f for f in args.dense_factors}
    if dense:
        training({"fixed f=1": None, **dense}, "dense", inputs, y, args.repeats)
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
