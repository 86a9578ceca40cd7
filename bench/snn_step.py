"""Time and peak memory of one SNN-6 training step: spikegyro vs. the same network in snnTorch.

One step = forward + backward of a window of T = 100 steps (1 ms each) of random input spikes
(1 % density) with the paper's loss shape (mean squared output from step 50 on). The snnTorch
build has the same convolutions (16-32-64-128-256, 3x3, strides 2-2-2-2-1, no padding, no bias),
snn.Synaptic neurons (the nearest equivalent of an SRM neuron: a second-order synapse +
membrane with decays exp(-1/τs), thresholds θ, subtractive reset) stepped in a Python loop over
T, spike-count pooling and a non-spiking Synaptic readout with τs = 8.

Each (implementation, resolution) runs in its own subprocess so that its peak resident memory
(``ru_maxrss``) is its own; the table reports the median step time of ``--repeats`` steps after
one warm-up, the peak RSS, and the peak growth over the RSS before the first step.

    .venv/bin/python bench/snn_step.py                   # 240x180 and 120x90, batch 1, 2 threads
    .venv/bin/python bench/snn_step.py --batch 16 --resolutions 240x180 --impls spikegyro
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import subprocess
import sys
import time

import torch
from torch import nn

STEPS = 100
DENSITY = 0.01


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _current_rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


class SnnTorchSNN6(nn.Module):
    """SNN-6 with snnTorch Synaptic neurons, one time step per call of the layers."""

    def __init__(self) -> None:
        import snntorch as snn
        from snntorch import surrogate

        from spikegyro.models.snn6 import SNN6_LAYERS

        super().__init__()
        channels, convs, neurons = 2, [], []
        for spec in SNN6_LAYERS:
            convs.append(nn.Conv2d(channels, spec.out_channels, 3, spec.stride, bias=False))
            decay = math.exp(-1.0 / spec.params.tau_s)
            neurons.append(
                snn.Synaptic(
                    alpha=decay,
                    beta=decay,
                    threshold=spec.params.theta,
                    spike_grad=surrogate.fast_sigmoid(),
                )
            )
            channels = spec.out_channels
        self.convs = nn.ModuleList(convs)
        self.neurons = nn.ModuleList(neurons)
        self.fc = nn.Linear(channels, 3, bias=False)
        readout_decay = math.exp(-1.0 / 8.0)
        self.readout = snn.Synaptic(alpha=readout_decay, beta=readout_decay, reset_mechanism="none")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # snnTorch neurons keep their state between calls; start each window from rest.
        for neuron in (*self.neurons, self.readout):
            neuron.reset_mem()
        outputs = []
        for t in range(x.shape[-1]):
            s = x[..., t]
            for conv, neuron in zip(self.convs, self.neurons, strict=True):
                s, _, _ = neuron(conv(s))
            _, _, mem = self.readout(self.fc(s.mean(dim=(2, 3))))
            outputs.append(mem)
        return torch.stack(outputs, dim=-1)


def _build(impl: str) -> nn.Module:
    if impl == "spikegyro":
        from spikegyro.models.snn6 import SNN6

        return SNN6()
    return SnnTorchSNN6()


def measure(impl: str, width: int, height: int, batch: int, repeats: int, threads: int) -> dict:
    """One configuration, in this process; returns seconds per step and memory in MiB."""
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    model = _build(impl)
    x = (torch.rand(batch, 2, height, width, STEPS) < DENSITY).float()

    def step() -> None:
        model.zero_grad(set_to_none=True)
        out = model(x)
        out[..., 50:].pow(2).mean().backward()

    before = _current_rss_mib()
    times = []
    for i in range(repeats + 1):
        start = time.perf_counter()
        step()
        if i:  # the first step warms up allocator and kernels
            times.append(time.perf_counter() - start)
    peak = _rss_mib()
    return {
        "impl": impl,
        "resolution": f"{width}x{height}",
        "batch": batch,
        "threads": threads,
        "step_s": statistics.median(times),
        "peak_rss_mib": peak,
        "peak_growth_mib": peak - before,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", nargs="+", default=["240x180", "120x90"])
    parser.add_argument("--impls", nargs="+", default=["spikegyro", "snntorch"])
    parser.add_argument("--batch", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: run one configuration
    args = parser.parse_args()

    if args.one:
        impl, resolution = args.one.split(":")
        width, height = (int(v) for v in resolution.split("x"))
        print(json.dumps(measure(impl, width, height, args.batch, args.repeats, args.threads)))
        return

    rows = []
    for resolution in args.resolutions:
        for impl in args.impls:
            command = [
                sys.executable,
                __file__,
                "--one",
                f"{impl}:{resolution}",
                "--batch",
                str(args.batch),
                "--repeats",
                str(args.repeats),
                "--threads",
                str(args.threads),
            ]
            result = subprocess.run(command, capture_output=True, text=True, check=True)
            rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
            r = rows[-1]
            print(
                f"  {r['impl']:10s} {r['resolution']:8s} {r['step_s']:7.2f} s/step  "
                f"peak RSS {r['peak_rss_mib']:7.0f} MiB (+{r['peak_growth_mib']:.0f})",
                file=sys.stderr,
            )

    print(
        f"SNN-6 training step (forward + backward), T = {STEPS}, batch {args.batch}, "
        f"input density {DENSITY:.0%}, torch {torch.__version__}, {args.threads} threads, "
        f"median of {args.repeats}"
    )
    print(
        "| resolution | implementation | step (s) | peak RSS (MiB) | growth (MiB) | "
        "time vs spikegyro |"
    )
    print("|---|---|---:|---:|---:|---:|")
    for resolution in args.resolutions:
        ours = next(
            (r for r in rows if r["resolution"] == resolution and r["impl"] == "spikegyro"), None
        )
        for r in (r for r in rows if r["resolution"] == resolution):
            ratio = f"{r['step_s'] / ours['step_s']:.2f}x" if ours else "-"
            print(
                f"| {resolution} | {r['impl']} | {r['step_s']:.2f} | {r['peak_rss_mib']:.0f} | "
                f"{r['peak_growth_mib']:.0f} | {ratio} |"
            )


if __name__ == "__main__":
    main()
