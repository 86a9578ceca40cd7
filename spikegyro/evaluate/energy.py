"""Operations and energy per angular-velocity estimate: SynOps for SNN-6, MACs for the ANNs.

**Counting.** SNN-6 runs event-driven: each spike costs one accumulate per outgoing synapse
(a synaptic operation, SynOp), counted from measured spikes by :mod:`spikegyro.evaluate.spikes`.
It estimates ω every 1 ms, so SynOps per estimate = SynOps per second of input × 1 ms. The ANNs
(ANN-6, ResNet-50) run densely once per ``target_ms`` window (20 ms): a convolution costs
``H_out·W_out·C_out·(C_in/groups)·k_h·k_w`` multiply-accumulates (MACs) per sample, a linear
layer ``in·out``; :func:`count_macs` adds these over a forward pass. Batch norm (foldable into
the preceding convolution at inference), ReLU, pooling and residual additions are not counted
(at most one operation per activation, where every output of a layer costs C_in·k² MACs).

**Energy** = operations × a published energy per operation (:data:`ENERGY_FIGURES`):

- Horowitz, "Computing's energy problem (and what we can do about it)", ISSCC 2014, 45 nm CMOS at
  0.9 V: 32-bit float add 0.9 pJ, multiply 3.7 pJ, so a MAC 4.6 pJ. An event-driven SynOp is an
  add (0.9 pJ) since input spikes are binary. These are arithmetic alone: fetching weights and
  activations from SRAM (5-10 pJ per 64-bit access at 8-32 kB) or DRAM (1.3-2.6 nJ) costs more
  than the arithmetic and is left out for both kinds of network, so the 45 nm figures compare
  arithmetic work, not chips. Newer nodes and 8-bit integer arithmetic are 10-100x cheaper.
- Davies et al., "Loihi: a neuromorphic manycore processor with on-chip learning", IEEE Micro
  38(1), 2018: 23.6 pJ per synaptic spike operation (the minimum), measured on the chip
  and including its memory traffic. Neuron updates (one per neuron per 1 ms step) and spike
  routing between cores are not counted, so it is a lower bound for SNN-6 on Loihi; SNN-6 would
  also have to be mapped onto Loihi's fixed-point neurons, which this number takes for granted.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from spikegyro.evaluate.spikes import STEP_S


@dataclass(frozen=True)
class EnergyFigure:
    """Energy of one operation (pJ) on a platform, with its source."""

    platform: str
    operation: str
    picojoules: float
    source: str


HOROWITZ_2014 = "Horowitz, ISSCC 2014, 45 nm"
ENERGY_FIGURES: dict[str, EnergyFigure] = {
    "mac_fp32_45nm": EnergyFigure("45 nm CMOS", "32-bit float MAC", 4.6, HOROWITZ_2014),
    "add_fp32_45nm": EnergyFigure("45 nm CMOS", "32-bit float add", 0.9, HOROWITZ_2014),
    "synop_loihi": EnergyFigure("Loihi", "synaptic op", 23.6, "Davies et al., IEEE Micro 2018"),
}
"""Per-operation energies used in reports; see the module docstring for how far each carries."""


def count_macs(model: nn.Module, example: torch.Tensor) -> int:
    """Multiply-accumulates of one forward pass of ``model`` per sample of ``example``.

    Conv layers: output elements × (C_in / groups) × kernel area; linear layers: output
    elements × in_features. Counted with forward hooks, so every executed layer counts once
    per call (shared layers count each time). ``example``'s first axis is the batch.
    """
    total = 0

    def conv_hook(module: nn.Conv2d, _inputs: Any, output: torch.Tensor) -> None:
        nonlocal total
        kernel = module.in_channels // module.groups * module.kernel_size[0] * module.kernel_size[1]
        total += output.numel() * kernel

    def linear_hook(module: nn.Linear, _inputs: Any, output: torch.Tensor) -> None:
        nonlocal total
        total += output.numel() * module.in_features

    handles = []
    for module in model.modules():
        if isinstance(module, nn.Conv2d):
            handles.append(module.register_forward_hook(conv_hook))
        elif isinstance(module, nn.Linear):
            handles.append(module.register_forward_hook(linear_hook))
    try:
        was_training = model.training
        model.eval()
        with torch.no_grad():
            model(example)
        model.train(was_training)
    finally:
        for handle in handles:
            handle.remove()
    return total // example.shape[0]


def snn_operations(spikes: Mapping[str, Any]) -> dict[str, Any]:
    """Operations per 1 ms estimate and per second of output of SNN-6, from ``evaluate``'s
    spike statistics (:func:`spikegyro.evaluate.spikes.spike_statistics`)."""
    per_second = float(spikes["synops_per_s"])
    return {
        "kind": "SynOps",
        "estimate_period_ms": STEP_S * 1e3,
        "per_estimate": per_second * STEP_S,
        "per_second": per_second,
        "dense_macs_per_estimate": float(spikes["dense_macs_per_s"]) * STEP_S,
    }


def ann_operations(macs_per_forward: int, target_ms: float) -> dict[str, Any]:
    """Operations of an ANN that predicts one mean ω per ``target_ms`` window (one forward)."""
    return {
        "kind": "MACs",
        "estimate_period_ms": float(target_ms),
        "per_estimate": float(macs_per_forward),
        "per_second": macs_per_forward * 1e3 / target_ms,
    }


def energy(operations: Mapping[str, Any]) -> dict[str, float]:
    """Energy (µJ) per estimate and power (mW = mJ/s) of ``operations`` on each platform that
    fits their kind: MACs on 45 nm float MACs; SynOps on 45 nm float adds and on Loihi."""
    keys = ("mac_fp32_45nm",) if operations["kind"] == "MACs" else ("add_fp32_45nm", "synop_loihi")
    out = {}
    for key in keys:
        pj = ENERGY_FIGURES[key].picojoules
        out[f"{key}_uj_per_estimate"] = operations["per_estimate"] * pj * 1e-6
        out[f"{key}_mw"] = operations["per_second"] * pj * 1e-9
    return out
