"""SNN-6 training step on the CPU: the dense torch path against the event-driven engine.

One step = forward + backward + Adam update of SNN-6 (240x180, T = 100 ms, batch 8, the shipped
weights, the same surrogate cut on both paths so that their gradients agree: ``--cut``, by default
the one ``spikegyro train --compute sparse`` uses) on realistic windows:
half simulated with the ideal sensor, half with the ``davis240c`` preset (seeded, the same every
run). Each path gets its input as ``spikegyro train`` gives it: the dense path the dense spike
tensor, the engine the same spikes as a sparse tensor binned from the windows' events (which it
reads without a dense copy; binning is outside both steps). Both paths run in one process, their
steps interleaved (so both see the same background load), on 1 and 2 threads; the time is the
median of ``--repeats`` steps after one warm-up step each, divided by the batch, as wall time and
as the process's CPU time, user and system apart. The process runs as ``spikegyro train`` runs
on a CPU: with malloc keeping freed memory (:func:`spikegyro.train.memory.keep_freed_memory`;
``--fresh-memory`` leaves glibc's default, under which the dense path's activations are mapped
and zeroed anew every step, the system time, which varies with the host's memory state), torch
on ``--threads`` threads for the dense path and on one beside the engine's threads for the
sparse path. Peak memory: one step of each path in its own subprocess (peak resident
set, VmHWM reset just before the step; growth = peak minus the level before it).

Gradients: on the same batch, the largest relative norm ‖g_sparse − g_dense‖/‖g_dense‖ over the
parameter tensors (float32), and the spikes that differ between the two forward passes (a
potential within float32 rounding of θ); how far the cut moves the gradient from SLAYER's
unbounded surrogate (cosine similarity per tensor, dense path, the same batch). Profile: where
the engine's time goes per layer in a warm step (CPU seconds of the threads that ran it, so that
waiting for a busy core does not count). The load average of the host before and after is
printed and written: on a shared machine only the interleaved ratio means anything.

    .venv/bin/python bench/train_step.py [--repeats 3] [--threads 1 2] [--cut C] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np
import torch

from spikegyro.models.registry import PRETRAINED_SNN6, load_checkpoint
from spikegyro.models.snn6 import SNN6
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.snn.sparse import _Plan
from spikegyro.train.data import (
    EventBatch,
    encode_batch,
    encode_target,
    encode_window,
    sequence_windows,
    window_events,
)
from spikegyro.train.loss import angular_velocity_loss
from spikegyro.train.memory import keep_freed_memory
from spikegyro.train.presets import SPARSE_DEFAULT_CUT
from spikegyro.train.throughput import train_step

BATCH = 8
STEPS = 100
START = 50
SPEC = {"representation": "spikes", "sensor": [240, 180], "scale": 1.0, "window_ms": STEPS}


def _status_mib(field: str) -> float:
    with open("/proc/self/status") as f:
        line = next(line for line in f if line.startswith(field + ":"))
    return int(line.split()[1]) / 1024.0


Inputs = dict[str, torch.Tensor]


def windows(seed: int = 7) -> tuple[Inputs, torch.Tensor]:
    """BATCH windows of 100 ms at 240x180, half ideal, half davis240c simulated sequences: the
    input of each path ("dense": (N, 2, H, W, T); "sparse": the same spikes as a sparse tensor)
    and the target."""
    picked = []
    for sensor in ("ideal", "davis240c"):
        config = SimConfig(duration_ms=STEPS, sensor=sensor)
        for i in range(BATCH // 2):
            recording = simulate_sequence(config, i, seed=seed)
            picked.append(sequence_windows(recording, STEPS, f"{sensor}:{i}")[0])
    y = torch.stack([encode_target(w, SPEC) for w in picked])
    events = EventBatch.concatenate([window_events(w, SPEC) for w in picked])
    inputs = {
        "dense": torch.stack([encode_window(w, SPEC) for w in picked]),
        "sparse": encode_batch(events, SPEC, sparse=True),
    }
    assert torch.equal(inputs["sparse"].to_dense(), inputs["dense"])
    return inputs, y


def model(compute: str, threads: int, cut: float) -> SNN6:
    net, _ = load_checkpoint(PRETRAINED_SNN6)
    net.train()
    net.set_surrogate_cut(cut)
    net.use_event_engine(threads if compute == "sparse" else None)
    return net


def make_step(
    compute: str, threads: int, x: Inputs, y, cut: float
) -> tuple[Callable[[], None], SNN6]:
    net = model(compute, threads, cut)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-5)
    # As `spikegyro train` runs each path: torch's own threads are the engine's for the dense
    # path; with the event engine torch keeps one (its ops are small).
    torch_threads = 1 if compute == "sparse" else threads

    def step() -> None:
        torch.set_num_threads(torch_threads)
        train_step(net, optimizer, x[compute], y, START)

    return step, net


def step_times(
    x: Inputs, y, threads: int, repeats: int, cut: float
) -> dict[str, tuple[float, float, float]]:
    """Median (wall, user CPU, system CPU) seconds per window of each path, steps interleaved,
    one warm-up step each. CPU time (all threads of the process) does not count waiting for a
    busy core; system time is mostly the kernel mapping and zeroing freshly allocated pages."""
    steps = {c: make_step(c, threads, x, y, cut)[0] for c in ("dense", "sparse")}
    for step in steps.values():
        step()
    times: dict[str, list[tuple[float, float, float]]] = {c: [] for c in steps}
    for _ in range(repeats):
        for compute, step in steps.items():
            start, cpu = time.perf_counter(), os.times()
            step()
            end = os.times()
            times[compute].append(
                (time.perf_counter() - start, end.user - cpu.user, end.system - cpu.system)
            )
    return {
        c: tuple(statistics.median(v[k] for v in t) / BATCH for k in (0, 1, 2))
        for c, t in times.items()
    }


def peak_memory(compute: str, threads: int, cut: float) -> dict[str, float]:
    """Peak resident set (MiB) of one step in this (fresh) process."""
    torch.set_num_threads(threads)
    x, y = windows()
    step, _ = make_step(compute, threads, x, y, cut)
    step()  # compile and warm up; the allocator keeps what it grew to
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    before = _status_mib("VmRSS")
    step()
    peak = _status_mib("VmHWM")
    return {"peak_mib": peak, "growth_mib": peak - before}


def dense_gradients(x: torch.Tensor, y, cut: float) -> dict[str, torch.Tensor]:
    """Every parameter's gradient by the dense path with surrogate ``cut`` (0: unbounded)."""
    torch.set_num_threads(2)
    net = model("dense", 2, cut)
    angular_velocity_loss(net(x), y, START).backward()
    return {n: p.grad.clone() for n, p in net.named_parameters()}


def gradient_check(inputs: Inputs, y, cut: float) -> dict:
    """Per-tensor relative gradient difference between the paths, cosine similarity of the
    cut's gradients to the unbounded surrogate's (dense path), and flipped spikes per layer
    (float32)."""
    dense = dense_gradients(inputs["dense"], y, cut)
    # Torch's threads as `spikegyro train` sets them: one beside the engine's two.
    torch.set_num_threads(1)
    net = model("sparse", 2, cut)
    for _ in range(2):  # the engine's second step is profiled: warm, as training runs it
        net.zero_grad()
        angular_velocity_loss(net(inputs["sparse"]), y, START).backward()
    timing = net.event_engine.timing
    sparse = {n: p.grad for n, p in net.named_parameters()}
    rel = {n: float((sparse[n] - g).norm() / g.norm()) for n, g in dense.items()}
    unbounded = dense_gradients(inputs["dense"], y, 0.0)
    cosine = {
        n: float(torch.nn.functional.cosine_similarity(g.flatten(), unbounded[n].flatten(), dim=0))
        for n, g in dense.items()
    }
    x = inputs["dense"]
    torch.set_num_threads(2)
    with torch.no_grad():
        _, dense_spikes = net.forward_with_spikes(x)
    plan = _Plan.of(net.convs, net.pool, (x.shape[2], x.shape[3]), np.float32, record=False)
    flips = [0] * len(net.convs)
    for b in range(x.shape[0]):
        element = plan.forward_element(x[b].numpy())
        outputs = [*element.inputs[1:], None]
        for i, spikes in enumerate(dense_spikes):
            s = spikes[b].permute(3, 1, 2, 0).reshape(STEPS, -1)  # (T, H·W·C) channels-last
            dense_set = set((s.nonzero()[:, 0] * s.shape[1] + s.nonzero()[:, 1]).tolist())
            if outputs[i] is None:
                continue  # the last layer's list is pooled, not kept; counted through its inputs
            offsets, index, _ = outputs[i]
            steps = np.repeat(np.arange(STEPS), np.diff(offsets))
            sparse_set = set((steps * s.shape[1] + index).tolist())
            flips[i] += len(dense_set ^ sparse_set)
    return {"relative": rel, "cosine": cosine, "flipped_spikes": flips[:-1], "timing": timing}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--json", help="write the headline numbers to this file")
    parser.add_argument(
        "--cut",
        type=float,
        default=SPARSE_DEFAULT_CUT,
        help=f"surrogate cut of both paths (default {SPARSE_DEFAULT_CUT}, the sparse engine's)",
    )
    parser.add_argument(
        "--fresh-memory", action="store_true", help="leave glibc's malloc at its default"
    )
    parser.add_argument("--memory-of", help=argparse.SUPPRESS)  # internal: COMPUTE:THREADS
    args = parser.parse_args()
    if not args.fresh_memory:
        keep_freed_memory()
    if args.memory_of:
        compute, threads = args.memory_of.split(":")
        print(json.dumps(peak_memory(compute, int(threads), args.cut)))
        return

    load_before = os.getloadavg()[0]
    x, y = windows()
    density = float(x["dense"].mean())
    rows = []
    for threads in args.threads:
        seconds = step_times(x, y, threads, args.repeats, args.cut)
        for compute in ("dense", "sparse"):
            command = [sys.executable, __file__, "--memory-of", f"{compute}:{threads}"]
            command += ["--cut", str(args.cut)]
            command += ["--fresh-memory"] if args.fresh_memory else []
            out = subprocess.run(command, capture_output=True, text=True, check=True).stdout
            memory = json.loads(out.strip().splitlines()[-1])
            wall, user, system = seconds[compute]
            rows.append({"compute": compute, "threads": threads, "s": wall, "user_s": user,
                         "system_s": system, "cpu_s": user + system, **memory})  # fmt: skip
            print(f"  {compute:6s} {threads} thr {wall:.3f} s/window", file=sys.stderr)
    check = gradient_check(x, y, args.cut)
    print(
        f"SNN-6 training step (forward + backward + Adam), 240x180, T = {STEPS}, batch {BATCH} "
        f"(4 ideal + 4 davis240c windows, input density {density:.2%}), surrogate cut {args.cut}, "
        f"torch {torch.__version__}, median of {args.repeats} interleaved steps"
    )
    print("| threads | path | s per window | dense / this | CPU s per window (user + system) "
          "| dense / this (CPU) | dense / this (user CPU) | peak RSS (MiB) "
          "| growth (MiB) |")  # fmt: skip
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        dense = next(o for o in rows if o["threads"] == r["threads"] and o["compute"] == "dense")
        print(
            f"| {r['threads']} | {r['compute']} | {r['s']:.3f} | {dense['s'] / r['s']:.2f}x | "
            f"{r['cpu_s']:.3f} ({r['user_s']:.3f} + {r['system_s']:.3f}) | "
            f"{dense['cpu_s'] / r['cpu_s']:.2f}x | {dense['user_s'] / r['user_s']:.2f}x | "
            f"{r['peak_mib']:.0f} | {r['growth_mib']:.0f} |"
        )
    rel = check["relative"]
    print("gradient relative norm difference per tensor: "
          + ", ".join(f"{n} {v:.1e}" for n, v in rel.items()))  # fmt: skip
    print(f"spikes that differ between the paths, layers 1-4: {check['flipped_spikes']}")
    cosine = ", ".join(f"{n} {v:.4f}" for n, v in check["cosine"].items())
    print(f"cosine similarity to the unbounded surrogate's gradients (dense path): {cosine}")
    t = check["timing"]
    print("engine profile (CPU s per batch of 8, summed over threads):")
    print("| layer | forward | backward | input spikes | active pairs |")
    print("|---:|---:|---:|---:|---:|")
    inputs = [t.inputs, *t.spikes]
    for i, (f, b) in enumerate(zip(t.layer_forward_s, t.layer_backward_s, strict=True)):
        print(f"| {i + 1} | {f:.2f} | {b:.2f} | {inputs[i]} | {t.active[i]} |")
    print(f"wall: forward {t.forward_s:.2f} s, backward {t.backward_s:.2f} s (2 threads)")
    load = [load_before, os.getloadavg()[0]]
    print(f"host load average (1 min) before / after: {load[0]:.1f} / {load[1]:.1f}, "
          f"{os.cpu_count()} cores")  # fmt: skip
    if args.json:
        two = {r["compute"]: r for r in rows if r["threads"] == max(args.threads)}
        result = {
            "dense_s_per_window": two["dense"]["s"],
            "sparse_s_per_window": two["sparse"]["s"],
            "speedup": two["dense"]["s"] / two["sparse"]["s"],
            "dense_cpu_s_per_window": two["dense"]["cpu_s"],
            "sparse_cpu_s_per_window": two["sparse"]["cpu_s"],
            "cpu_speedup": two["dense"]["cpu_s"] / two["sparse"]["cpu_s"],
            "dense_system_s_per_window": two["dense"]["system_s"],
            "sparse_system_s_per_window": two["sparse"]["system_s"],
            "user_cpu_speedup": two["dense"]["user_s"] / two["sparse"]["user_s"],
            "threads": max(args.threads),
            "surrogate_cut": args.cut,
            "malloc_keeps_freed_memory": not args.fresh_memory,
            "max_grad_rel_diff": max(rel.values()),
            "grad_rel_diff": rel,
            "cosine_to_unbounded": check["cosine"],
            "flipped_spikes": check["flipped_spikes"],
            "peak_mib": {f"{r['compute']}_{r['threads']}": r["peak_mib"] for r in rows},
            "profile_cpu_s": {"forward": t.layer_forward_s, "backward": t.layer_backward_s},
            "active_pairs": t.active,
            "load_average": load,
            "cores": os.cpu_count(),
            "date": time.strftime("%Y-%m-%d"),
        }
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
