"""What the NIR export of SNN-6 costs: run the exported graph in snnTorch and compare its ω.

The checkpoint is exported with :func:`spikegyro.models.nir.to_nir`, written to and read back from
a ``.nir`` file, and turned into a PyTorch module by ``nirtorch.nir_to_torch`` with snnTorch
neurons (``snn.Synaptic``, a current-based LIF with reset to zero) at dt = 1 ms, one step per
input bin; its ω is compared with our SNN-6's on the fixed test windows of a simulated dataset.

snnTorch's own ``import_from_nir`` is not used: it fixes dt = 0.1 ms and reads spikes as unit
pulses per step rather than NIR's unit-area impulses (``r`` must equal τ_mem / 0.1 ms), so it
cannot run a graph that follows NIR's equations at 1 ms steps. The node map below is the import
at dt = 1 ms: synaptic and membrane decay exp(−dt/τ), and the potential scaled by ``gain`` so
that snnTorch's potential, sampled at step k, equals the NIR membrane potential at (k + 1) ms
(``--discretization exact``), or by the forward-Euler gain dt·R·w_in/(τ_mem·τ_syn)
(``--discretization euler``, what a generic ODE importer does). In both, the reset to zero replaces
SNN-6's refractory kernel, and snnTorch's neuron reacts in the step of its input spike where
SNN-6's ε[0] = 0 delays each layer by one step (6 steps over 5 layers and the readout).

    .venv/bin/python bench/nir_snntorch.py --data DIR --checkpoint best.pt [--limit N]

Needs the ``bench`` and ``nir`` extras (snntorch, nir, nirtorch).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import nir
import nirtorch
import numpy as np
import snntorch as snn
import torch
from snntorch import utils as snn_utils

from spikegyro import metrics
from spikegyro.models.nir import read_nir, to_nir
from spikegyro.models.registry import load_checkpoint
from spikegyro.train.data import InputSpec, encode_window, fixed_windows
from spikegyro.train.infer import predict_windows

DT_S = 1e-3


def membrane_gain(node: nir.NIRNode, discretization: str) -> float:
    """NIR membrane potential per unit of snnTorch's ``mem`` for a CubaLI(F) node at dt = 1 ms.

    snnTorch: syn[k] = α·syn[k−1] + x[k], mem[k] = β·mem[k−1] + syn[k]; an input spike is x = 1.
    NIR: a unit impulse lifts I by w_in/τ_syn; v then follows τ_mem·dv/dt = −v + R·I.
    """
    tau_syn = float(np.asarray(node.tau_syn).flat[0])
    tau_mem = float(np.asarray(node.tau_mem).flat[0])
    gain = float(np.asarray(node.r).flat[0] * np.asarray(node.w_in).flat[0]) / tau_syn
    if discretization == "euler":
        return gain * DT_S / tau_mem
    if not math.isclose(tau_syn, tau_mem):
        raise ValueError("exact sampling is implemented for τ_syn = τ_mem only")
    # v(t) = gain/τ·t·e^(−t/τ) for a unit impulse at 0; snnTorch's mem[k] = (k+1)·α^k.
    return gain / tau_mem * DT_S * math.exp(-DT_S / tau_mem)


class Readout(torch.nn.Module):
    """A non-spiking CubaLI in snnTorch: the membrane of a Synaptic neuron that never fires."""

    def __init__(self, alpha: float, beta: float, gain: float) -> None:
        super().__init__()
        self.neuron = snn.Synaptic(
            alpha=alpha, beta=beta, threshold=1e30, reset_mechanism="none", init_hidden=True,
            output=True,
        )  # fmt: skip
        self.gain = gain

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _, _, mem = self.neuron(x)
        return mem * self.gain


def snntorch_module(graph: nir.NIRGraph, discretization: str) -> torch.nn.Module:
    """The NIR graph as a torch module of snnTorch neurons at dt = 1 ms (one call per step)."""

    def decays(node: nir.NIRNode) -> tuple[float, float]:
        tau_syn = float(np.asarray(node.tau_syn).flat[0])
        tau_mem = float(np.asarray(node.tau_mem).flat[0])
        return math.exp(-DT_S / tau_syn), math.exp(-DT_S / tau_mem)

    def cubalif(node: nir.CubaLIF) -> torch.nn.Module:
        alpha, beta = decays(node)
        threshold = float(np.asarray(node.v_threshold).flat[0]) / membrane_gain(
            node, discretization
        )
        return snn.Synaptic(
            alpha=alpha, beta=beta, threshold=threshold, reset_mechanism="zero",
            init_hidden=True, reset_delay=False,
        )  # fmt: skip

    def cubali(node: nir.CubaLI) -> torch.nn.Module:
        return Readout(*decays(node), membrane_gain(node, discretization))

    def flatten(node: nir.Flatten) -> torch.nn.Module:
        # NIR's axes exclude the batch; torch's start with it.
        return torch.nn.Flatten(start_dim=node.start_dim + 1)

    node_map = {
        **nirtorch.nir_interpreter.DEFAULT_MAP,
        nir.CubaLIF: cubalif,
        nir.CubaLI: cubali,
        nir.Flatten: flatten,
    }
    return nirtorch.nir_to_torch(graph, node_map)


@torch.no_grad()
def run_snntorch(net: torch.nn.Module, x: torch.Tensor) -> torch.Tensor:
    """(N, 3, T) output of ``net`` over (N, 2, H, W, T) input spikes, one step per bin."""
    snn_utils.reset(net)
    out = []
    for t in range(x.shape[-1]):
        y = net(x[..., t].contiguous())
        out.append(y[0] if isinstance(y, tuple) else y)
    return torch.stack(out, dim=-1)


def compare(pred_ours: np.ndarray, pred_nir: np.ndarray, gt: np.ndarray) -> dict:
    """Metrics of both predictions vs the truth, and of their difference (steps ≥ 50)."""
    ours, theirs = metrics.summary(pred_ours, gt), metrics.summary(pred_nir, gt)
    diff = np.degrees(np.linalg.norm(pred_nir - pred_ours, axis=-1))[:, metrics.EVAL_START_STEP :]
    rel = metrics.summary(pred_nir, pred_ours)
    keys = ("median_relative_error", "mean_euclidean_error_deg_s", "rmse_deg_s")
    return {
        "spikegyro": {k: ours[k] for k in keys},
        "snntorch_from_nir": {k: theirs[k] for k in keys},
        "difference": {
            "mean_euclidean_deg_s": float(diff.mean()),
            "median_euclidean_deg_s": float(np.median(diff)),
            "median_relative_to_spikegyro": rel["median_relative_error"],
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--split", default="test")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--discretization", choices=("exact", "euler", "both"), default="both")
    parser.add_argument("--out", type=Path, default=None, help="Write the results as JSON.")
    args = parser.parse_args()

    model, payload = load_checkpoint(args.checkpoint)
    spec = InputSpec.from_dict(payload["input"])
    windows = fixed_windows(args.data, args.split, spec.window_ms)[: args.limit]
    gt = np.stack([w.omega for w in windows])
    start = time.perf_counter()
    ours = predict_windows(model, spec, windows, args.batch_size)
    ours_s = time.perf_counter() - start

    height, width = (round(s * spec.scale) for s in spec.sensor[::-1])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "snn6.nir"
        nir.write(path, to_nir(model, height, width))
        reread, _ = read_nir(path)
        graph = nir.read(path)
    same = all(
        torch.equal(a, b)
        for a, b in zip(model.state_dict().values(), reread.state_dict().values(), strict=True)
    )
    kinds = ("exact", "euler") if args.discretization == "both" else (args.discretization,)
    results = {
        "windows": len(windows),
        "data": str(args.data / args.split),
        "checkpoint": str(args.checkpoint),
        "round_trip_weights_identical": same,
        "spikegyro_seconds": ours_s,
    }
    for kind in kinds:
        net = snntorch_module(graph, kind)
        start = time.perf_counter()
        pred = np.zeros_like(ours)
        for i in range(0, len(windows), args.batch_size):
            chunk = windows[i : i + args.batch_size]
            x = torch.stack([encode_window(w, spec) for w in chunk])
            pred[i : i + len(chunk)] = run_snntorch(net, x).permute(0, 2, 1).numpy()
        seconds = time.perf_counter() - start
        shifted = np.concatenate([pred[:, :1].repeat(6, axis=1), pred[:, :-6]], axis=1)
        results[kind] = {
            **compare(ours, pred, gt),
            "delayed_6_steps": compare(ours, shifted, gt),
            "snntorch_seconds": seconds,
        }
        print(f"{kind}: {json.dumps(results[kind], indent=1)}", flush=True)
    print(json.dumps({k: v for k, v in results.items() if k not in kinds}, indent=1))
    if args.out:
        args.out.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
