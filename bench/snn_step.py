"""Time and peak memory of one SNN-6 training step: spikegyro vs. the same network in snnTorch.

One step = forward + backward of a window of T = 100 steps (1 ms each) of random input spikes
(1 % density) with the paper's loss shape (mean squared output from step 50 on). The snnTorch
build has the same convolutions (16-32-64-128-256, 3x3, strides 2-2-2-2-1, no padding, no bias),
snn.Synaptic neurons (the nearest equivalent of an SRM neuron: a second-order synapse +
membrane with decays exp(-1/τs), thresholds θ, subtractive reset) stepped in a Python loop over
T, GASP (spatial mean of layer-5 spikes) and a non-spiking Synaptic readout with τs = 8.

Step times: both implementations in one process, steps interleaved (so both see the same
background load), median of ``--repeats`` after one warm-up step each. Memory: one step of each
(implementation, resolution) in its own subprocess, peak resident set (VmHWM, reset just before
the step); "growth" is that peak minus the resident set before the step.
The ratio column is time / spikegyro's time at the same resolution (the first implementation
listed is the reference).

    .venv/bin/python bench/snn_step.py                   # 240x180 and 120x90, batch 1, 2 threads
    .venv/bin/python bench/snn_step.py --batch 16 --resolutions 240x180 --impls spikegyro
    .venv/bin/python bench/snn_step.py --device cuda
    .venv/bin/python bench/snn_step.py --batch 8 --resolutions 240x180 \
        --impls spikegyro spikegyro-freeze4
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import torch
from torch import nn

STEPS = 100
DENSITY = 0.01


def _status_mib(field: str) -> float:
    with open("/proc/self/status") as f:
        line = next(line for line in f if line.startswith(field + ":"))
    return int(line.split()[1]) / 1024.0  # kB


def _reset_peak_rss() -> None:
    # Writing 5 to clear_refs resets the peak resident set (VmHWM) to the current one (Linux).
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


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
    """``spikegyro``, ``spikegyro-freezeN`` (its first N spiking layers frozen, as ``train
    --freeze N``) or ``snntorch``."""
    if impl.startswith("spikegyro"):
        from spikegyro.models.snn6 import SNN6

        model = SNN6()
        frozen = impl.removeprefix("spikegyro-freeze")
        model.freeze(0 if frozen == impl else int(frozen))
        return model
    return SnnTorchSNN6()


def _make_step(impl: str, resolution: str, batch: int, device: str) -> Callable[[], None]:
    """A closure running one training step of ``impl`` on a fixed random input window."""
    width, height = (int(v) for v in resolution.split("x"))
    torch.manual_seed(0)
    model = _build(impl).to(device)
    x = (torch.rand(batch, 2, height, width, STEPS, device=device) < DENSITY).float()

    def step() -> None:
        model.zero_grad(set_to_none=True)
        out = model(x)
        out[..., 50:].pow(2).mean().backward()
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    return step


def peak_memory(impl: str, resolution: str, batch: int, device: str) -> dict:
    """Peak memory (MiB) of one step, run in a fresh process: resident set on the CPU, the
    allocator's peak on a GPU; ``growth`` is the peak minus the level before the step."""
    step = _make_step(impl, resolution, batch, device)
    if device.startswith("cuda"):
        before = torch.cuda.memory_allocated() / 2**20
        step()
        peak = torch.cuda.max_memory_allocated() / 2**20
    else:
        _reset_peak_rss()
        before = _status_mib("VmRSS")
        step()
        peak = _status_mib("VmHWM")
    return {"peak_mib": peak, "growth_mib": peak - before}


def step_times(resolution: str, impls: list[str], batch: int, repeats: int, device: str) -> dict:
    """Median seconds per step of each implementation, their steps interleaved so that both
    see the same background load; one warm-up step each first."""
    steps = {impl: _make_step(impl, resolution, batch, device) for impl in impls}
    for step in steps.values():
        step()
    times: dict[str, list[float]] = {impl: [] for impl in impls}
    for _ in range(repeats):
        for impl, step in steps.items():
            start = time.perf_counter()
            step()
            times[impl].append(time.perf_counter() - start)
    return {impl: statistics.median(t) for impl, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", nargs="+", default=["240x180", "120x90"])
    parser.add_argument("--impls", nargs="+", default=["spikegyro", "snntorch"])
    parser.add_argument("--batch", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--memory-of", help=argparse.SUPPRESS)  # internal: IMPL:RESOLUTION
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    if args.memory_of:
        impl, resolution = args.memory_of.split(":")
        print(json.dumps(peak_memory(impl, resolution, args.batch, args.device)))
        return

    rows = []
    for resolution in args.resolutions:
        seconds = step_times(resolution, args.impls, args.batch, args.repeats, args.device)
        for impl in args.impls:
            command = [sys.executable, __file__, "--memory-of", f"{impl}:{resolution}"]
            command += ["--batch", str(args.batch), "--threads", str(args.threads)]
            command += ["--device", args.device]
            result = subprocess.run(command, capture_output=True, text=True, check=True)
            memory = json.loads(result.stdout.strip().splitlines()[-1])
            rows.append({"impl": impl, "resolution": resolution, "step_s": seconds[impl], **memory})
            r = rows[-1]
            print(
                f"  {impl:10s} {resolution:8s} {r['step_s']:7.2f} s/step  "
                f"peak {r['peak_mib']:7.0f} MiB (+{r['growth_mib']:.0f})",
                file=sys.stderr,
            )

    memory_kind = "GPU allocator peak" if args.device.startswith("cuda") else "peak RSS"
    print(
        f"SNN-6 training step (forward + backward), T = {STEPS}, batch {args.batch}, input "
        f"density {DENSITY:.0%}, torch {torch.__version__} on {args.device}, {args.threads} "
        f"threads, median of {args.repeats} interleaved steps"
    )
    print(
        f"| resolution | implementation | step (s) | {memory_kind} (MiB) | growth (MiB) | "
        "time / spikegyro time |"
    )
    print("|---|---|---:|---:|---:|---:|")
    for r in rows:
        ours = next(o for o in rows if o["resolution"] == r["resolution"])
        print(
            f"| {r['resolution']} | {r['impl']} | {r['step_s']:.2f} | {r['peak_mib']:.0f} | "
            f"{r['growth_mib']:.0f} | {r['step_s'] / ours['step_s']:.2f}x |"
        )


if __name__ == "__main__":
    main()
