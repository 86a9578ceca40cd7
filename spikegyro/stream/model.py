"""From a trained SNN (module or checkpoint) to the stateful streaming engine."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from torch import nn

from spikegyro.errors import InputError
from spikegyro.models.registry import PRETRAINED_SNN6, load_checkpoint
from spikegyro.snn.layers import GASP, SRMConv, SRMDense
from spikegyro.stream.stateful import SNNSpec, SRMLayerSpec, StreamingSNN

DEFAULT_CHECKPOINT = PRETRAINED_SNN6
"""The shipped pretrained SNN-6 (``spikegyro/data/pretrained/snn6.pt``)."""


def _numpy(tensor: Any, dtype: type) -> np.ndarray:
    return tensor.detach().cpu().numpy().astype(dtype)


def spec_from_model(
    model: nn.Module, input_shape: tuple[int, int, int], dtype: type = np.float32
) -> SNNSpec:
    """Describe a feed-forward SRM network: its :class:`SRMConv` layers in order, a :class:`GASP`
    pooling and a non-spiking :class:`SRMDense` readout (SNN-6 and its variants).

    Args:
        model: the network (e.g. :class:`spikegyro.models.snn6.SNN6`).
        input_shape: (2, height, width) of the input spike tensor.
        dtype: dtype of weights and kernels in the spec (float64 for bit-level comparisons).
    """
    children = list(model.modules())
    convs = [m for m in children if isinstance(m, SRMConv)]
    dense = [m for m in children if isinstance(m, SRMDense)]
    if not convs or len(dense) != 1 or not any(isinstance(m, GASP) for m in children):
        raise InputError(
            f"model {type(model).__name__}: streaming needs spiking conv layers, global average "
            "spike pooling and one dense readout (an SNN such as snn6), not this architecture."
        )
    if any(c.padding for c in convs) or dense[0].params.spiking:
        raise InputError(
            f"model {type(model).__name__}: streaming supports unpadded convolutions and a "
            "non-spiking readout only."
        )
    layers = tuple(
        SRMLayerSpec(
            weight=_numpy(c.weight, dtype),
            stride=int(c.stride),
            theta=float(c.params.theta),
            srm_kernel=_numpy(c.srm_kernel, dtype),
            ref_kernel=_numpy(c.ref_kernel, dtype),
        )
        for c in convs
    )
    return SNNSpec(
        input_shape=tuple(int(v) for v in input_shape),
        layers=layers,
        fc_weight=_numpy(dense[0].weight, dtype).reshape(dense[0].weight.shape[0], -1),
        out_kernel=_numpy(dense[0].srm_kernel, dtype),
    )


def input_shape_of(input_spec: dict[str, Any]) -> tuple[int, int, int]:
    """(2, height, width) of the spike tensor a checkpoint's ``input`` spec describes."""
    width, height = (int(v) for v in input_spec.get("sensor", (240, 180)))
    scale = float(input_spec.get("scale", 1.0))
    return 2, max(1, round(height * scale)), max(1, round(width * scale))


def load_streaming_model(path: str | os.PathLike) -> tuple[StreamingSNN, dict[str, Any]]:
    """Load a checkpoint and build its streaming engine; returns (engine, checkpoint dict)."""
    path = Path(path)
    if not path.exists():
        if path == DEFAULT_CHECKPOINT:
            raise InputError(
                f"{path}: no pretrained model is installed; train one with 'spikegyro train' and "
                "pass --checkpoint PATH."
            )
        raise InputError(f"{path}: no such checkpoint file.")
    model, payload = load_checkpoint(path)
    spec = payload.get("input", {})
    if spec.get("representation", "spikes") != "spikes" or spec.get("output") == "window_mean":
        raise InputError(
            f"{path}: model '{payload.get('model')}' takes {spec.get('representation')} windows; "
            "predict streams spiking networks (spike input, one output per step) only."
        )
    return StreamingSNN(spec_from_model(model, input_shape_of(spec))), payload
