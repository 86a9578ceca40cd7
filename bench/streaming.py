"""Real-time factor of streaming SNN-6 (240x180, one CPU thread): event-driven vs naive dense.

Both run the same network step by step (1 ms per step, state carried over) on simulated test
sequences, in the same process:

- event-driven: :class:`spikegyro.stream.stateful.StreamingSNN` (Numba; sparse scatter of the
  synaptic input, exact recursions for the PSP and refractory kernels, dense work only on pixels
  touched in the last few ms);
- naive dense: per step and layer, the PSP of the input over a ring buffer of past input maps
  (the truncated FIR), a full ``torch.conv2d``, the refractory response from a ring of future
  potentials, and the threshold (torch, dense tensors).

Real-time factor = seconds of events processed per second of wall time (> 1: keeps up with the
camera). The two outputs are compared on the steps both ran.

    .venv/bin/python bench/streaming.py [--sequences 3] [--duration-ms 500] [--dense-steps 200]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
import torch.nn.functional as F

from spikegyro.models.registry import load_checkpoint
from spikegyro.models.snn6 import INIT_GAIN, SNN6
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.stateful import SNNSpec, StreamingSNN


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


def simulated_sequences(n: int, duration_ms: int, seed: int) -> list:
    config = SimConfig(duration_ms=duration_ms)
    return [simulate_sequence(config, i, seed, split="test") for i in range(n)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=3)
    parser.add_argument("--duration-ms", type=int, default=500)
    parser.add_argument("--dense-steps", type=int, default=200, help="steps of the dense run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
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
    dtype = np.dtype(args.dtype).type

    if args.checkpoint:
        model, payload = load_checkpoint(args.checkpoint)
        spec_in = payload["input"]
        if tuple(spec_in.get("sensor", (240, 180))) != (240, 180) or spec_in.get("scale", 1) != 1:
            raise SystemExit(f"{args.checkpoint}: the bench runs at 240x180, scale 1")
    else:
        model = SNN6(init_gain=args.gain).eval()  # random weights scaled so every layer spikes
    spec = spec_from_model(model, (2, 180, 240))
    engine = StreamingSNN(spec, dtype=dtype)
    engine.run(np.zeros(1, np.int64), np.array([0, 1, 1]))  # compile (or load the cache)

    t_sim = time.perf_counter()
    sequences = simulated_sequences(args.sequences, args.duration_ms, args.seed)
    print(
        f"simulated {len(sequences)} test sequences of {args.duration_ms} ms at 240x180 "
        f"in {time.perf_counter() - t_sim:.1f} s; one CPU thread, state dtype {args.dtype}, "
        + (args.checkpoint or f"random SNN-6 with init gain {args.gain}")
    )
    header = (
        f"{'seq':>3} {'events':>8} {'input%':>6} {'spikes/step L1..L5 (% of neurons)':>36}"
        f" {'event-driven':>13} {'dense':>8} {'speed-up':>8} {'max |diff|':>10}"
    )
    print(header)
    totals = np.zeros(6)  # wall, cpu, steps for event-driven; the same for dense
    n_neurons = np.array([c * h * w for c, h, w in spec.layer_shapes()])
    for i, rec in enumerate(sequences):
        ev = rec.events
        steps = args.duration_ms
        k = ev.t // 1000
        index = (ev.y.astype(np.int64) * 240 + ev.x) * 2 + ev.p
        offsets = np.searchsorted(k, np.arange(steps + 1))
        engine.reset()
        start, cpu = time.perf_counter(), time.process_time()
        out = engine.run(index, offsets)
        wall_ev, cpu_ev = time.perf_counter() - start, time.process_time() - cpu
        rates = engine.spike_counts / steps / n_neurons * 100

        dense = DenseStepper(spec)
        n_dense = min(args.dense_steps, steps)
        frames = np.zeros((n_dense, 2, 180, 240), np.float32)
        keep = k < n_dense
        frames[k[keep], ev.p[keep], ev.y[keep], ev.x[keep]] = 1.0
        frames_t = torch.from_numpy(frames)
        start, cpu = time.perf_counter(), time.process_time()
        out_dense = torch.stack([dense.step(frames_t[s]) for s in range(n_dense)]).numpy()
        wall_dense, cpu_dense = time.perf_counter() - start, time.process_time() - cpu
        diff = np.abs(out_dense - out[:n_dense]).max()

        active = np.mean([np.unique(index[offsets[s] : offsets[s + 1]]).size for s in range(steps)])
        rtf_ev = steps / 1000 / wall_ev
        rtf_dense = n_dense / 1000 / wall_dense
        rate_text = " ".join(f"{r:5.2f}" for r in rates)
        print(
            f"{i:>3} {len(ev):>8} {active / (2 * 240 * 180) * 100:>6.2f} {rate_text:>36} "
            f"{rtf_ev:>12.2f}x {rtf_dense:>7.3f}x {rtf_ev / rtf_dense:>7.1f}x {diff:>10.2e}"
        )
        totals += (wall_ev, cpu_ev, steps, wall_dense, cpu_dense, n_dense)
    w_ev, c_ev, n_ev, w_de, c_de, n_de = totals
    for label, t_ev, t_de in (("wall time", w_ev, w_de), ("CPU time", c_ev, c_de)):
        print(
            f"all, {label}: event-driven {n_ev / 1000 / t_ev:.2f}x real time "
            f"({t_ev / n_ev * 1e6:.0f} us/step), naive dense {n_de / 1000 / t_de:.3f}x "
            f"({t_de / n_de * 1e6:.0f} us/step), speed-up {(t_de / n_de) / (t_ev / n_ev):.1f}x"
        )


if __name__ == "__main__":
    main()
