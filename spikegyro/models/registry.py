"""Model registry and the checkpoint format shared by training, evaluation and prediction.

A checkpoint is a ``torch.save``'d dict::

    {
        "format": "spikegyro-checkpoint/1",
        "model": "snn6",                      # registry name
        "model_kwargs": {...},                # passed to the constructor
        "input": {...},                       # how events become the model's input (see below)
        "state_dict": {...},
        "extra": {...},                       # training config, step, metrics, ... (optional)
    }

``input`` is a plain dict: ``representation`` ("spikes", "voxel" or "frames"), ``sensor``
([width, height] of the events the model was trained on), ``scale`` (factor applied to event
coordinates before binning), ``window_ms`` and, for ANNs, ``num_bins``/``target_ms``. Models
producing one angular velocity per millisecond say ``"output": "per_step"``; ANNs that predict
the mean over each window say ``"output": "window_mean"``.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn

from spikegyro.errors import InputError
from spikegyro.pretrained import (  # noqa: F401  (re-exported: the registry's API)
    DEFAULT_NAME,
    PRETRAINED_DIR,
    bundled_names,
    bundled_path,
    model_card,
    resolve_checkpoint,
)

CHECKPOINT_FORMAT = "spikegyro-checkpoint/1"

PRETRAINED_SNN6 = bundled_path(DEFAULT_NAME)
"""The shipped pretrained SNN-6 (model card ``snn6.md``); the default model of ``predict`` and
``evaluate``."""

_REGISTRY: dict[str, Callable[..., nn.Module]] = {}


def register(name: str) -> Callable[[Callable[..., nn.Module]], Callable[..., nn.Module]]:
    """Class decorator: make a model constructible by name from a checkpoint."""

    def wrap(factory: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        _REGISTRY[name] = factory
        return factory

    return wrap


def model_names() -> list[str]:
    """Names of all registered models."""
    return sorted(_REGISTRY)


def check_model_kwargs(name: str, kwargs: dict[str, Any], partial: bool = False) -> None:
    """Raise :class:`InputError` unless model ``name`` exists and takes ``kwargs`` (all its
    required arguments among them, unless ``partial``)."""
    if name not in _REGISTRY:
        raise InputError(f"unknown model '{name}'; choose one of {', '.join(model_names())}.")
    signature = inspect.signature(_REGISTRY[name])
    try:
        (signature.bind_partial if partial else signature.bind)(**kwargs)
    except TypeError as exc:
        accepted = ", ".join(signature.parameters) or "none"
        raise InputError(
            f"--model-kwargs {kwargs}: {exc} for model '{name}'; it takes: {accepted}."
        ) from None


def build_model(name: str, **kwargs: Any) -> nn.Module:
    """Construct a registered model."""
    check_model_kwargs(name, kwargs)
    return _REGISTRY[name](**kwargs)


def save_checkpoint(
    path: str | os.PathLike,
    model: nn.Module,
    *,
    name: str,
    model_kwargs: dict[str, Any],
    input_spec: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a checkpoint atomically (temp file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    payload = {
        "format": CHECKPOINT_FORMAT,
        "model": name,
        "model_kwargs": model_kwargs,
        "input": input_spec,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "extra": extra or {},
    }
    torch.save(payload, tmp)
    os.replace(tmp, path)
    return path


def training_before(payload: dict[str, Any] | None) -> dict[str, float]:
    """Steps and seconds of training before a checkpoint's own run: the runs it was continued
    from with ``--init`` (``extra["before"]``; zero when there were none)."""
    before = (payload or {}).get("extra", {}).get("before") or {}
    return {"steps": int(before.get("steps", 0)), "elapsed_s": float(before.get("elapsed_s", 0))}


def training_total(payload: dict[str, Any]) -> dict[str, float]:
    """All the training behind a checkpoint (its run and those before): what a run started from
    it with ``--init`` records as its ``extra["before"]``."""
    extra, before = payload.get("extra", {}), training_before(payload)
    return {
        "steps": before["steps"] + int(extra.get("step", 0)),
        "elapsed_s": before["elapsed_s"] + float(extra.get("elapsed_s", 0.0)),
    }


def read_checkpoint(path: str | os.PathLike, option: str = "checkpoint") -> dict[str, Any]:
    """Load a checkpoint dict (on the CPU) from a file or a bundled name (``"ann6"``), with clear
    errors for missing or foreign files; ``option`` names the source in error messages."""
    path = resolve_checkpoint(path, option)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for corrupt files
        raise InputError(f"{path}: not a readable PyTorch checkpoint ({exc}).") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise InputError(
            f"{path}: not a spikegyro checkpoint; for the paper's official weights use "
            "load_official()."
        )
    return payload


def load_checkpoint(
    path: str | os.PathLike, option: str = "checkpoint"
) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model stored in ``path`` (a file or a bundled name); returns (model in eval
    mode, checkpoint dict)."""
    payload = read_checkpoint(path, option)
    model = build_model(payload["model"], **payload["model_kwargs"])
    try:
        model.load_state_dict(payload["state_dict"])
    except RuntimeError as exc:
        first = str(exc).splitlines()[0:3]
        raise InputError(
            f"{path}: weights do not fit model '{payload['model']}': {' '.join(first)}"
        ) from None
    model.eval()
    return model, payload
