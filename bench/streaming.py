"""Real-time factor of streaming SNN-6 (240x180): event-driven on 1 and 2 threads vs naive dense.

All run the same network step by step (1 ms per step, state carried over) on simulated test
sequences, in the same process, one after the other on each sequence:

- event-driven: :class:`spikegyro.stream.stateful.StreamingSNN` (Numba; sparse scatter of the
  synaptic input, exact recursions for the PSP and refractory kernels, dense work only on pixels
  touched in the last few ms), with ``threads=1`` and with ``threads=2`` (the layers split in
  two stages that run as a pipeline on two cores);
- naive dense: per step and layer, the PSP of the input over a ring buffer of past input maps
  (the truncated FIR), a full ``torch.conv2d``, the refractory response from a ring of future
  potentials, and the threshold (torch, dense tensors, one thread).

Real-time factor = seconds of events processed per second of wall time (> 1: keeps up with the
camera); CPU time (``time.process_time``, all threads of the process) is printed beside it, as
on a shared machine wall time includes waiting for a core. The dense ratio (event-driven speed
over dense speed) is measured on the same events in the same run, so it is comparable across
machines and loads. The outputs of all paths are compared on the steps they share, and the
float32 engine against a float64 one (the accuracy cost of single precision). The last table is
the single-thread engine's own cycle-counter profile: microseconds per step per layer and kind
of work.

    .venv/bin/python bench/streaming.py --checkpoint CKPT [--sequences 3] [--duration-ms 500]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch
import torch.nn.functional as F

from spikegyro.models.registry import load_checkpoint
from spikegyro.models.snn6 import INIT_GAIN, SNN6
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.stateful import PROFILE_KINDS, SNNSpec, StreamingSNN


class DenseStepper:
    """The straightforward per-step execution: dense tensors, a full convolution every step."""

    def __init__(self, spec: SNNSpec) -> None:
        self.spec = spec
        shapes = [spec.input_shape, *spec.layer_shapes()]
        self.layers = []
        for layer, shape_in, shape_out in zip(spec.layers, shapes[:-1], shapes[1:], strict=True):
            eps, nu = torch.from_numpy(layer.srm_kernel), torch.from_numpy(layer.ref_kernel)
            self.layers.append(
                {
                    "w": torch.from_numpy(layer.weight),
                    "stride": layer.stride,
                    "theta": layer.theta,
                    "eps": eps,
                    "nu": nu,
                    "ring": torch.zeros(len(eps), *shape_in),
                    "future": torch.zeros(len(nu), *shape_out),
                }
            )
        self.fc = torch.from_numpy(spec.fc_weight).float()
        self.eps_out = torch.from_numpy(spec.out_kernel).float()
        self.h = torch.zeros(len(self.eps_out), self.fc.shape[0])
        self.t = 0

    @torch.no_grad()
    def step(self, x: torch.Tensor) -> torch.Tensor:
        t = self.t
        for lay in self.layers:
            eps, ring, future, nu = lay["eps"], lay["ring"], lay["future"], lay["nu"]
            ring[t % len(eps)] = x
            # psp[t] = sum_k eps[k] ring[t - k]: reorder the taps instead of the ring
            taps = torch.zeros(len(ring)).index_copy_(
                0, (t - torch.arange(len(eps))) % len(ring), eps
            )
            psp = torch.tensordot(taps, ring, dims=1)
            u = F.conv2d(psp[None], lay["w"], stride=lay["stride"])[0]
            slot = t % len(nu)
            u += future[slot]
            future[slot] = 0
            x = (u >= lay["theta"]).float()
            # nu[k] lands on step t + k, i.e. ring slot (t + k) % len(nu), k >= 1
            order = (t + torch.arange(1, len(nu))) % len(nu)
            future[order] += nu[1:, None, None, None] * x
        self.h[t % len(self.h)] = self.fc @ x.mean(dim=(1, 2))
        taps = torch.zeros(len(self.h)).index_copy_(
            0, (t - torch.arange(len(self.eps_out))) % len(self.h), self.eps_out
        )
        self.t += 1
        return taps @ self.h

    def run(self, frames: torch.Tensor) -> np.ndarray:
        """Step through (steps, 2, H, W) input frames; the readout, (steps, outputs)."""
        return torch.stack([self.step(frame) for frame in frames]).numpy()


def simulated_sequences(n: int, duration_ms: int, seed: int) -> list:
    config = SimConfig(duration_ms=duration_ms)
    return [simulate_sequence(config, i, seed, split="test") for i in range(n)]


def timed(fn, *args) -> tuple[np.ndarray, float, float]:
    """(result, wall seconds, CPU seconds of the whole process)."""
    start, cpu = time.perf_counter(), time.process_time()
    result = fn(*args)
    return result, time.perf_counter() - start, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=3)
    parser.add_argument("--duration-ms", type=int, default=500)
    parser.add_argument("--dense-steps", type=int, default=200, help="steps of the dense run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--block-steps", type=int, default=16, help="engine block, ms")
    parser.add_argument(
        "--gain",
        type=float,
        default=INIT_GAIN,
        help="random weights uniform in +-gain/sqrt(fan_in) (lower: sparser spiking)",
    )
    parser.add_argument("--checkpoint", help="a trained SNN-6 checkpoint instead of random weights")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)

    if args.checkpoint:
        model, payload = load_checkpoint(args.checkpoint)
        spec_in = payload["input"]
        if tuple(spec_in.get("sensor", (240, 180))) != (240, 180) or spec_in.get("scale", 1) != 1:
            raise SystemExit(f"{args.checkpoint}: the bench runs at 240x180, scale 1")
    else:
        model = SNN6(init_gain=args.gain).eval()  # random weights scaled so every layer spikes
    spec = spec_from_model(model, (2, 180, 240))
    engines = {
        threads: StreamingSNN(spec, threads=threads, block_steps=args.block_steps)
        for threads in (1, 2)
    }
    exact = StreamingSNN(spec_from_model(model, (2, 180, 240), np.float64), np.float64)
    for engine in (*engines.values(), exact):  # compile (or load the cache)
        engine.run(np.zeros(1, np.int64), np.array([0, 1, 1]))

    t_sim = time.perf_counter()
    sequences = simulated_sequences(args.sequences, args.duration_ms, args.seed)
    print(
        f"simulated {len(sequences)} test sequences of {args.duration_ms} ms at 240x180 "
        f"in {time.perf_counter() - t_sim:.1f} s; {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f}; block {args.block_steps} ms; "
        + (args.checkpoint or f"random SNN-6 with init gain {args.gain}")
    )
    print(
        f"{'seq':>3} {'events':>8} {'input%':>6} {'spikes/step L1..L5 (% of neurons)':>36}"
        f" {'1 thread':>9} {'2 threads':>9} {'dense':>8} {'dense ratio':>11}"
        f" {'max|d| 2thr':>11} {'max|d| dense':>12} {'max|d| f64':>10}"
    )
    # wall, cpu, steps per path; profile of the one-thread engine, cycles -> seconds
    totals = {key: np.zeros(3) for key in ("1 thread", "2 threads", "dense")}
    profile = np.zeros((len(spec.layers) + 1, len(PROFILE_KINDS)))
    n_neurons = np.array([c * h * w for c, h, w in spec.layer_shapes()])
    for i, rec in enumerate(sequences):
        ev = rec.events
        steps = args.duration_ms
        k = ev.t // 1000
        index = (ev.y.astype(np.int64) * 240 + ev.x) * 2 + ev.p
        offsets = np.searchsorted(k, np.arange(steps + 1))
        outs, rtf = {}, {}
        for threads, engine in engines.items():
            engine.reset()
            key = "1 thread" if threads == 1 else "2 threads"
            outs[key], wall, cpu = timed(engine.run, index, offsets)
            totals[key] += (wall, cpu, steps)
            rtf[key] = steps / 1000 / wall
        profile += engines[1].profile()
        rates = engines[1].spike_counts / steps / n_neurons * 100
        exact.reset()
        out64 = exact.run(index, offsets)

        dense = DenseStepper(spec)
        n_dense = min(args.dense_steps, steps)
        frames = np.zeros((n_dense, 2, 180, 240), np.float32)
        keep = k < n_dense
        frames[k[keep], ev.p[keep], ev.y[keep], ev.x[keep]] = 1.0
        frames_t = torch.from_numpy(frames)
        out_dense, wall, cpu = timed(dense.run, frames_t)
        totals["dense"] += (wall, cpu, n_dense)
        rtf["dense"] = n_dense / 1000 / wall

        one = outs["1 thread"]
        active = np.mean([np.unique(index[offsets[s] : offsets[s + 1]]).size for s in range(steps)])
        rate_text = " ".join(f"{r:5.2f}" for r in rates)
        print(
            f"{i:>3} {len(ev):>8} {active / (2 * 240 * 180) * 100:>6.2f} {rate_text:>36}"
            f" {rtf['1 thread']:>8.2f}x {rtf['2 threads']:>8.2f}x {rtf['dense']:>7.3f}x"
            f" {rtf['1 thread'] / rtf['dense']:>10.1f}x"
            f" {np.abs(outs['2 threads'] - one).max():>11.1e}"
            f" {np.abs(out_dense - one[:n_dense]).max():>12.1e}"
            f" {np.abs(out64 - one).max():>10.1e}"
        )
    dense_us = totals["dense"][0] / totals["dense"][2] * 1e6
    for key in ("1 thread", "2 threads", "dense"):
        wall, cpu, n = totals[key]
        ratio = "" if key == "dense" else f", dense ratio {dense_us / (wall / n * 1e6):.1f}x"
        print(
            f"all, {key:>9}: {n / 1000 / wall:6.3f}x real time ({wall / n * 1e6:6.0f} us/step "
            f"wall, {cpu / n * 1e6:6.0f} us/step CPU){ratio}"
        )
    steps_total = totals["1 thread"][2]
    per_step = profile / steps_total * 1e6
    print(f"\nwhere the one-thread time goes (us per step, cycle counter; {PROFILE_KINDS}):")
    print(f"{'layer':>8} " + " ".join(f"{kind:>13}" for kind in PROFILE_KINDS)
          + f" {'total':>8} {'share':>6}")  # fmt: skip
    grand = per_step.sum()
    for li, row in enumerate(per_step[:-1]):
        print(f"{li + 1:>8} " + " ".join(f"{v:>13.1f}" for v in row)
              + f" {row.sum():>8.1f} {row.sum() / grand * 100:>5.1f}%")  # fmt: skip
    io = per_step[-1]
    print(f"{'input':>8} {io[0]:>13.1f}  readout {io[1]:.1f}; total {grand:.0f} us/step "
          f"(wall of the same runs: {totals['1 thread'][0] / steps_total * 1e6:.0f})")  # fmt: skip


if __name__ == "__main__":
    main()
