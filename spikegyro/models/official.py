"""Load a checkpoint of the official SNN-6 repository (uzh-rpg/snn_angular_velocity).

The official file is ``torch.save({'model_state_dict': state, ...})`` of a SLAYER model whose
weights are Conv3d kernels with a trailing time axis of size 1:

    conv1.weight … conv5.weight   (out, in, 3, 3, 1)
    fc.weight                     (3, 256, 1, 1, 1)
    slayer_conv1.srmKernel, slayer_conv1.refKernel, … slayer_conv5.*   1-D kernel buffers
    slayer_fc.srmKernel (and slayer_fc.refKernel, unused: the readout does not spike)
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from spikegyro.errors import InputError
from spikegyro.models.snn6 import SNN6


def _expected_weights(model: SNN6) -> dict[str, tuple[int, ...]]:
    shapes = {f"conv{i}.weight": (*conv.weight.shape, 1) for i, conv in enumerate(model.convs, 1)}
    shapes["fc.weight"] = (*model.fc.weight.shape, 1, 1, 1)
    return shapes


def _kernel_targets(model: SNN6) -> dict[str, tuple[torch.nn.Module, str | None]]:
    """Official kernel buffer name → (our layer, our buffer name or None when unused)."""
    targets: dict[str, tuple[torch.nn.Module, str | None]] = {}
    for i, conv in enumerate(model.convs, 1):
        targets[f"slayer_conv{i}.srmKernel"] = (conv, "srm_kernel")
        targets[f"slayer_conv{i}.refKernel"] = (conv, "ref_kernel")
    targets["slayer_fc.srmKernel"] = (model.fc, "srm_kernel")
    targets["slayer_fc.refKernel"] = (model.fc, None)
    return targets


def _read_state(path: Path) -> dict[str, torch.Tensor]:
    if not path.exists():
        raise InputError(f"{path}: no such checkpoint file.")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:
        # Training checkpoints may also pickle non-tensor extras (optimizer state, configs).
        try:
            payload = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:  # torch raises many types for corrupt or foreign files
            raise InputError(f"{path}: not a readable PyTorch checkpoint ({exc}).") from None
    state = payload.get("model_state_dict", payload) if isinstance(payload, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(
            f"{path}: not an official SNN-6 checkpoint (expected a dict with 'model_state_dict')."
        )
    # Models saved from DataParallel prefix every key with 'module.'.
    return {k.removeprefix("module."): v for k, v in state.items()}


def load_official(path: str | os.PathLike, *, use_stored_kernels: bool = False) -> SNN6:
    """Build an :class:`SNN6` holding the weights of an official checkpoint (in eval mode).

    Args:
        path: the official ``.pth``/``.pt`` file.
        use_stored_kernels: take the PSP and refractory kernels stored in the file instead of the
            ones computed from the layer parameters (they agree for the released model).

    Raises:
        InputError: the file is missing, unreadable, or has missing, unexpected or misshapen
            entries (all of them named in the message).
    """
    path = Path(path)
    state = _read_state(path)
    model = SNN6()
    weights = _expected_weights(model)
    kernels = _kernel_targets(model)
    missing = sorted(set(weights) - set(state))
    unexpected = sorted(set(state) - set(weights) - set(kernels))
    misshapen = [
        f"{name} {tuple(state[name].shape)} (expected {shape})"
        for name, shape in weights.items()
        if name in state and tuple(state[name].shape) != shape
    ]
    misshapen += [
        f"{name} {tuple(state[name].shape)} (expected a 1-D kernel)"
        for name in kernels
        if name in state and state[name].dim() != 1
    ]
    problems = []
    if missing:
        problems.append("missing " + ", ".join(missing))
    if unexpected:
        problems.append("unexpected " + ", ".join(unexpected))
    if misshapen:
        problems.append("wrong shape " + ", ".join(misshapen))
    if problems:
        raise InputError(
            f"{path}: does not match the official SNN-6 layout: {'; '.join(problems)}."
        )

    with torch.no_grad():
        for name in weights:
            module = model.get_submodule(name.rsplit(".", 1)[0])
            module.weight.copy_(state[name].reshape(module.weight.shape))
    if use_stored_kernels:
        for name, (layer, buffer) in kernels.items():
            if buffer is None or name not in state:
                continue
            kernel = state[name].to(torch.float32)
            if buffer == "ref_kernel" and float(kernel[0]) != 0.0:
                raise InputError(f"{path}: {name}[0] = {float(kernel[0])}; it must be 0.")
            setattr(layer, buffer, kernel.clone())
    return model.eval()
