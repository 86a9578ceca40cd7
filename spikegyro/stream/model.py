"""From a trained SNN (module or checkpoint) to the stateful streaming engine.

Building the engine needs only the network's weights and constants (an :class:`SNNSpec`), not
torch: the first load of a checkpoint derives the spec with torch and keeps it in a small
``.npz`` in the user's cache, keyed by the checkpoint's SHA-256, so later loads (every
``spikegyro predict`` after the first) neither import torch nor unpickle the checkpoint.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.pretrained import DEFAULT_NAME, bundled_path, resolve_checkpoint
from spikegyro.stream.stateful import SNNSpec, SRMLayerSpec, StreamingSNN

if TYPE_CHECKING:
    from torch import nn

DEFAULT_CHECKPOINT = bundled_path(DEFAULT_NAME)
"""The shipped pretrained SNN-6 (``spikegyro.models.registry.PRETRAINED_SNN6``, taken from the
torch-free :mod:`spikegyro.pretrained` because importing :mod:`spikegyro.models` imports torch)."""

SPEC_CACHE_VERSION = 1


class BatchedOnly(InputError):
    """A network the exact stream engine cannot run, but the batched torch path can."""


_META_KEYS = ("format", "model", "model_kwargs", "input")


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
    from spikegyro.snn.layers import GASP, RegionPool, SRMConv, SRMDense

    children = list(model.modules())
    convs = [m for m in children if isinstance(m, SRMConv)]
    dense = [m for m in children if isinstance(m, SRMDense)]
    pooled = any(isinstance(m, (GASP, RegionPool)) for m in children)
    if convs and getattr(model, "log_polar", False):  # conv1 also takes the log-polar copy
        input_shape = (int(convs[0].weight.shape[1]), *input_shape[1:])
    if not convs or len(dense) != 1 or not pooled:
        raise InputError(
            f"model {type(model).__name__}: streaming needs spiking conv layers, average "
            "spike pooling and one dense readout (an SNN such as snn6), not this architecture."
        )
    if any(c.padding for c in convs) or dense[0].params.spiking:
        raise InputError(
            f"model {type(model).__name__}: streaming supports unpadded convolutions and a "
            "non-spiking readout only."
        )
    for layer in (*convs, *dense):
        layer.refresh_kernels()  # learned time constants: the kernels at the current τ
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


def spec_cache_dir() -> Path:
    """Where derived specs live: ``$SPIKEGYRO_CACHE``, else ``$XDG_CACHE_HOME/spikegyro``, else
    ``~/.cache/spikegyro``."""
    if os.environ.get("SPIKEGYRO_CACHE"):
        return Path(os.environ["SPIKEGYRO_CACHE"])
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "spikegyro"


def save_spec(path: str | os.PathLike, spec: SNNSpec, meta: dict[str, Any]) -> Path:
    """Write ``spec`` and the JSON-able ``meta`` to an ``.npz`` (atomically; no pickles)."""
    from spikegyro.events.io import atomic_path  # not on the torch-free load path

    arrays: dict[str, np.ndarray] = {
        "input_shape": np.array(spec.input_shape, np.int64),
        "fc_weight": spec.fc_weight,
        "out_kernel": spec.out_kernel,
        "meta": np.array(json.dumps({**meta, "spec_version": SPEC_CACHE_VERSION})),
    }
    for i, layer in enumerate(spec.layers):
        arrays[f"layer{i}_weight"] = layer.weight
        arrays[f"layer{i}_srm_kernel"] = layer.srm_kernel
        arrays[f"layer{i}_ref_kernel"] = layer.ref_kernel
        arrays[f"layer{i}_stride_theta"] = np.array([layer.stride, layer.theta], np.float64)
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    return path


def load_spec(path: str | os.PathLike) -> tuple[SNNSpec, dict[str, Any]]:
    """Read what :func:`save_spec` wrote; returns (spec, meta)."""
    with np.load(path, allow_pickle=False) as f:
        meta = json.loads(str(f["meta"]))
        layers = []
        while f"layer{len(layers)}_weight" in f:
            i = len(layers)
            stride, theta = f[f"layer{i}_stride_theta"]
            layers.append(
                SRMLayerSpec(
                    weight=f[f"layer{i}_weight"],
                    stride=int(stride),
                    theta=float(theta),
                    srm_kernel=f[f"layer{i}_srm_kernel"],
                    ref_kernel=f[f"layer{i}_ref_kernel"],
                )
            )
        spec = SNNSpec(
            input_shape=tuple(int(v) for v in f["input_shape"]),
            layers=tuple(layers),
            fc_weight=f["fc_weight"],
            out_kernel=f["out_kernel"],
        )
    return spec, meta


def _check_streamable(path: Path, meta: dict[str, Any]) -> None:
    spec = meta.get("input", {})
    if spec.get("representation", "spikes") != "spikes" or spec.get("output") == "window_mean":
        raise InputError(
            f"{path}: model '{meta.get('model')}' takes {spec.get('representation')} windows; "
            "predict streams spiking networks (spike input, one output per step) only."
        )


def load_streaming_spec(path: str | os.PathLike) -> tuple[SNNSpec, dict[str, Any]]:
    """The :class:`SNNSpec` of a checkpoint and its metadata (format, model, model_kwargs,
    input; no weights), from the spec cache when it holds this exact file, else through torch
    (then cached; a cache that cannot be written is skipped). ``path``: a file or a bundled
    name."""
    path = resolve_checkpoint(path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    cached = spec_cache_dir() / f"snn-spec-{digest[:24]}.npz"
    if cached.exists():
        try:
            spec, meta = load_spec(cached)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):
            pass  # unreadable (another version wrote it?): derive it again
        else:
            if meta.get("sha256") == digest and meta.get("spec_version") == SPEC_CACHE_VERSION:
                _check_streamable(path, meta)
                return spec, meta
    from spikegyro.models.registry import load_checkpoint

    model, payload = load_checkpoint(path)
    meta = {key: payload.get(key) for key in _META_KEYS}
    _check_streamable(path, meta)
    spec = spec_from_model(model, input_shape_of(meta["input"] or {}))
    try:
        cached.parent.mkdir(parents=True, exist_ok=True)
        save_spec(cached, spec, {**meta, "sha256": digest})
    except OSError:
        pass  # a read-only home: every run derives the spec, nothing else changes
    return spec, meta


def load_streaming_model(
    path: str | os.PathLike, threads: int = 1
) -> tuple[StreamingSNN, dict[str, Any]]:
    """Build the streaming engine of a checkpoint; returns (engine, metadata without weights)."""
    spec, meta = load_streaming_spec(path)
    if spec.input_shape[0] != 2 or spec.fc_weight.shape[1] != spec.layers[-1].weight.shape[0]:
        raise BatchedOnly(
            f"{path}: the exact stream engine runs Cartesian spike input and global average "
            "spike pooling only, not log-polar channels or a grid readout"
        )
    return StreamingSNN(spec, threads=threads), meta
