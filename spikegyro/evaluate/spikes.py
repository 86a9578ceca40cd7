"""Spike statistics of SNN-6: firing rates per layer and synaptic operations per second.

Synaptic operations (SynOps) are the usual basis of energy estimates on neuromorphic hardware:
each spike costs one accumulate per outgoing synapse, whatever the weight. For a layer with a
``k x k`` convolution, stride ``s``, no padding and ``C_out`` output channels, an input spike at
pixel (y, x) reaches ``C_out * n(y) * n(x)`` neurons, where ``n(y)`` counts the output rows whose
receptive field ``[i*s, i*s + k)`` holds ``y`` (about ``(k / s)^2 * C_out`` away from borders):

    SynOps(layer) = C_out * sum over (c, y, x, t) of s_in[c, y, x, t] * n(y) * n(x)

The input spikes of conv1 are the binned events; conv5's spikes feed GASP and the 256 -> 3
readout, costing 3 synaptic operations each: the spatial mean is a fixed scaling folded into the
readout weights, so GASP + readout is one dense layer from every conv5 neuron to 3 outputs.
Rates are per second of input (steps of 1 ms). Beside them we report the multiply-accumulates
(MACs) the same network needs per second when run densely every 1 ms (conv layers:
``C_out * H_out * W_out * C_in * k^2``, readout: ``3 * C * H * W`` per step), so their ratio is
the saving that event-driven execution gets from sparsity.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from spikegyro.evaluate.report import Table, fmt
from spikegyro.train.data import InputSpec, Window, encode_window

STEP_S = 1e-3


@dataclass(frozen=True)
class ConvGeometry:
    """A spiking convolution's connectivity: square ``kernel`` (px), ``stride`` (px), no padding."""

    kernel: int = 3
    stride: int = 1


def receptive_counts(size_in: int, size_out: int, geometry: ConvGeometry) -> np.ndarray:
    """n(y): for each input coordinate, how many of the ``size_out`` outputs see it, (size_in,)."""
    counts = np.zeros(size_in, dtype=np.int64)
    for i in range(size_out):
        counts[i * geometry.stride : i * geometry.stride + geometry.kernel] += 1
    return counts


def conv_synops(spikes_in: np.ndarray, out_shape: Sequence[int], geometry: ConvGeometry) -> int:
    """Synaptic operations of one conv layer given its input spike counts.

    Args:
        spikes_in: per-pixel spike counts summed over batch, channels and time, (H_in, W_in).
        out_shape: (C_out, H_out, W_out) of the layer's output.
    """
    c_out, h_out, w_out = out_shape
    ny = receptive_counts(spikes_in.shape[0], h_out, geometry)
    nx = receptive_counts(spikes_in.shape[1], w_out, geometry)
    return int(c_out * (ny @ spikes_in.astype(np.int64) @ nx))


def dense_macs_per_step(in_shape: Sequence[int], out_shape: Sequence[int], kernel: int) -> int:
    """MACs of one dense evaluation of a conv layer: C_out * H_out * W_out * C_in * k^2."""
    c_out, h_out, w_out = out_shape
    return int(c_out * h_out * w_out * in_shape[0] * kernel * kernel)


def layer_statistics(
    inputs: torch.Tensor,
    spikes: Sequence[torch.Tensor],
    geometries: Sequence[ConvGeometry],
    readout_outputs: int = 3,
) -> dict[str, Any]:
    """Firing rates and SynOps from one batch of inputs and each layer's output spikes.

    Args:
        inputs: (N, C, H, W, T) binary input spikes (the encoded events).
        spikes: per conv layer, (N, C_l, H_l, W_l, T) output spikes.
        geometries: per conv layer, its kernel and stride.
        readout_outputs: outputs of the dense readout fed by the last layer's spikes.

    Returns:
        JSON-ready dict: ``seconds`` of input (N * T * 1 ms), ``input`` (events-bins per pixel
        per second), per ``layers`` entry: ``neurons``, ``spikes``, ``rate_hz`` (mean spikes per
        neuron per second), ``synops`` (caused by this layer's *input*), ``dense_macs_per_step``;
        and totals.
    """
    n, _, _, _, steps = inputs.shape
    seconds = n * steps * STEP_S
    layers = []
    previous = inputs
    for index, (out, geometry) in enumerate(zip(spikes, geometries, strict=True)):
        counts_in = previous.detach().sum(dim=(0, 1, 4)).double().cpu().numpy()
        shape_in, shape_out = previous.shape[1:4], out.shape[1:4]
        neurons = int(np.prod(shape_out))
        total = float(out.detach().sum().item())
        layers.append(
            {
                "layer": f"conv{index + 1}",
                "shape": list(shape_out),
                "neurons": neurons,
                "spikes": total,
                "rate_hz": total / (neurons * seconds),
                "synops": conv_synops(counts_in, shape_out, geometry),
                "dense_macs_per_step": dense_macs_per_step(shape_in, shape_out, geometry.kernel),
            }
        )
        previous = out
    last = float(previous.detach().sum().item())
    layers.append(
        {
            "layer": "readout",
            "shape": [readout_outputs],
            "neurons": readout_outputs,
            "spikes": None,
            "rate_hz": None,
            "synops": round(last) * readout_outputs,
            "dense_macs_per_step": int(np.prod(previous.shape[1:4])) * readout_outputs,
        }
    )
    synops = sum(layer["synops"] for layer in layers)
    macs = sum(layer["dense_macs_per_step"] for layer in layers)
    input_pixels = int(np.prod(inputs.shape[2:4]))
    return {
        "seconds": seconds,
        "input_rate_hz": float(inputs.detach().sum().item()) / (input_pixels * seconds),
        "layers": layers,
        "synops_per_s": synops / seconds,
        "dense_macs_per_s": macs / STEP_S,
        "dense_macs_over_synops": (macs / STEP_S) / (synops / seconds) if synops else None,
    }


@torch.no_grad()
def spike_statistics(
    model: torch.nn.Module,
    spec: InputSpec,
    windows: list[Window],
    device: str | torch.device = "cpu",
    batch_size: int = 4,
    progress: Any = None,
) -> dict[str, Any]:
    """:func:`layer_statistics` of an SNN over ``windows`` (summed over batches, all T steps).

    The model must provide ``forward_with_spikes(x) -> (out, [spikes per conv layer])`` and
    ``convs``, its spiking convolutions (``weight`` (C_out, C_in, k, k), ``stride``, no padding),
    as :class:`spikegyro.models.snn6.SNN6` does. ``progress(done_windows)`` is called after each
    batch when given.
    """
    if not windows:
        return {"windows": 0, "note": "no window with events to measure spikes on"}
    if any(conv.padding for conv in model.convs):
        raise ValueError("SynOps counting assumes unpadded convolutions")
    geometries = [ConvGeometry(conv.weight.shape[-1], conv.stride) for conv in model.convs]
    totals: dict[str, Any] | None = None
    for i in range(0, len(windows), batch_size):
        x = torch.stack([encode_window(w, spec) for w in windows[i : i + batch_size]]).to(device)
        _, spikes = model.forward_with_spikes(x)
        stats = layer_statistics(x, spikes, geometries)
        totals = stats if totals is None else _merge(totals, stats)
        if progress is not None:
            progress(min(i + batch_size, len(windows)))
    assert totals is not None
    return {"windows": len(windows), **totals}


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Combine the statistics of two batches (rates weighted by their seconds of input)."""
    seconds = a["seconds"] + b["seconds"]
    layers = []
    for la, lb in zip(a["layers"], b["layers"], strict=True):
        merged = dict(la, synops=la["synops"] + lb["synops"])
        if la["spikes"] is not None:
            merged["spikes"] = la["spikes"] + lb["spikes"]
            merged["rate_hz"] = merged["spikes"] / (la["neurons"] * seconds)
        layers.append(merged)
    synops = sum(layer["synops"] for layer in layers)
    input_rate = (a["input_rate_hz"] * a["seconds"] + b["input_rate_hz"] * b["seconds"]) / seconds
    return {
        **a,
        "seconds": seconds,
        "input_rate_hz": input_rate,
        "layers": layers,
        "synops_per_s": synops / seconds,
        "dense_macs_over_synops": a["dense_macs_per_s"] / (synops / seconds) if synops else None,
    }


def spike_table(stats: dict[str, Any]) -> Table:
    """The spike statistics as a report table."""
    if not stats.get("windows"):
        return Table("Spike statistics", ["note"], [[stats.get("note", "not measured")]])
    rows = [["input (events)", "-", "-", fmt(stats["input_rate_hz"], 2), "-", "-"]]
    for layer in stats["layers"]:
        rows.append(
            [
                layer["layer"],
                " x ".join(str(v) for v in layer["shape"]),
                fmt(layer["neurons"]),
                fmt(layer["rate_hz"], 2),
                f"{layer['synops'] / stats['seconds']:.3g}",
                f"{layer['dense_macs_per_step'] / STEP_S:.3g}",
            ]
        )
    ratio = stats["dense_macs_over_synops"]
    rows.append(
        [
            "total",
            "-",
            "-",
            "-",
            f"{stats['synops_per_s']:.3g}",
            f"{stats['dense_macs_per_s']:.3g}" + (f" ({ratio:.1f}x SynOps)" if ratio else ""),
        ]
    )
    return Table(
        f"Spiking activity over {stats['windows']} windows ({stats['seconds']:g} s of input): "
        "firing rate = spikes per neuron per second; SynOps/s = synaptic operations caused by "
        "the layer's input spikes per second of input; dense MAC/s = the same layer run densely "
        "every 1 ms",
        ["layer", "output (C x H x W)", "neurons", "rate [Hz]", "SynOps/s", "dense MAC/s"],
        rows,
    )
