"""SNN-6 as a Neuromorphic Intermediate Representation (NIR) graph, and back.

NIR (Pedersen et al., Nature Communications 2024; the ``nir`` package, optional extra ``nir``)
describes networks in continuous time (seconds), spikes being unit-area Dirac impulses. The graph
of SNN-6 for an H x W input is a chain::

    input (2, H, W)
    -> [Conv2d (3x3, stride s_l, no padding, zero bias) -> CubaLIF] x 5
    -> AvgPool2d (kernel = stride = the layer-5 map) -> Flatten -> Linear (3 x 256)
    -> CubaLI -> output (3)

**Neuron mapping.** NIR's CubaLIF is

    τ_syn dI/dt = −I + w_in·S,     τ_mem dv/dt = (v_leak − v) + R·I,     spike when v > v_th.

With τ_syn = τ_mem = τ, v_leak = 0 and w_in = 1, one input spike at t = 0 gives
v(t) = (R/τ²)·t·exp(−t/τ); with R = e·τ this is exactly the SRM kernel ε(t) = (t/τ)·exp(1 − t/τ)
of SNN-6 in continuous time. So each layer exports τ_syn = τ_mem = τs (s), R = e·τs (s),
w_in = 1, v_th = θ, v_leak = 0, v_reset = 0; the readout (non-spiking, τs = 8 ms) is a CubaLI
with the same mapping.

**What NIR does not carry exactly** (what another framework then computes differently):

1. *Refractoriness.* SNN-6 adds ν[k] = −2θ·exp(−(k−1)/τr) to a neuron's potential after each of
   its spikes and keeps integrating its input (the PSP is not reset). NIR's CubaLIF resets v to
   v_reset (0) instead, and has no τr. τr and the refractory scale are kept in the nodes'
   ``metadata`` (key ``spikegyro``) for our own import only.
2. *Discrete time.* SNN-6 samples ε at whole milliseconds, ε[0] = 0, so every layer delays by one
   step and a spike in bin k acts from step k + 1; a simulator of the NIR equations at time step
   dt chooses its own discretization (Euler or exponential, with or without that delay), and
   every layer of SNN-6 fires within one step of a sampling difference.
3. *Kernel truncation.* SNN-6 drops ε's taps once they fall under 0.01 (after the peak); the
   continuous kernel has an infinite tail.
4. *Threshold test.* SNN-6 fires at u ≥ θ, NIR at v > v_th (immaterial for real-valued v).

:func:`from_nir` reads a graph back into :class:`~spikegyro.models.snn6.SNN6` where the mapping is
exact: the weights, θ (checked against SNN-6's), τs and τr from the metadata when present. A
network whose time constants were learned (``SNN6(learn_tau=True)``) exports them per layer and
comes back as such a network.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikegyro.errors import InputError
from spikegyro.events.io import atomic_path
from spikegyro.models.registry import read_checkpoint
from spikegyro.models.snn6 import READOUT, SNN6, SNN6_LAYERS
from spikegyro.snn.kernels import TAU_MAX_MS, TAU_MIN_MS
from spikegyro.snn.layers import SRMParams

NIR_EXTRA = "nir"
MS = 1e-3
"""Seconds per millisecond: NIR's time unit is the second, SNN-6's the 1 ms step."""

METADATA_KEY = "spikegyro"


def require_nir() -> Any:
    """The ``nir`` module, or an :class:`InputError` naming the extra that provides it."""
    try:
        import nir
    except ImportError:
        raise InputError(
            "NIR export/import needs the 'nir' package: pip install 'spikegyro[nir]'."
        ) from None
    return nir


def cubalif_parameters(params: SRMParams, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """NIR CubaLI(F) fields (SI units) whose impulse response is SNN-6's ε, per neuron of ``shape``.

    τ_syn = τ_mem = τs (s), R = e·τs (s), w_in = 1, v_leak = 0; for a spiking layer also
    v_threshold = θ and v_reset = 0 (the reset replaces the refractory kernel, see the module
    docstring).
    """
    tau = params.tau_s * MS
    full = lambda value: np.full(shape, value, dtype=np.float32)  # noqa: E731
    fields = {
        "tau_syn": full(tau),
        "tau_mem": full(tau),
        "r": full(math.e * tau),
        "v_leak": full(0.0),
        "w_in": full(1.0),
    }
    if params.spiking:
        fields["v_threshold"] = full(params.theta)
        fields["v_reset"] = full(0.0)
    return fields


def srm_tau_ms(node: Any, name: str) -> float:
    """τs (ms) of a CubaLI(F) node that follows :func:`cubalif_parameters`'s mapping exactly.

    Raises InputError naming the node when it is not an alpha-PSP neuron of one τ per layer.
    """
    tau_syn, tau_mem = np.asarray(node.tau_syn), np.asarray(node.tau_mem)
    tau = float(tau_syn.flat[0])
    gain = np.asarray(node.r) * np.asarray(node.w_in)
    checks = {
        "one τ_syn per layer": np.allclose(tau_syn, tau, rtol=1e-6),
        "τ_mem = τ_syn": np.allclose(tau_mem, tau_syn, rtol=1e-6),
        "R·w_in = e·τ": np.allclose(gain, math.e * tau, rtol=1e-6),
        "v_leak = 0": np.allclose(node.v_leak, 0.0),
    }
    failed = [what for what, ok in checks.items() if not ok]
    if failed:
        raise InputError(
            f"NIR node '{name}': not an SRM neuron with an alpha PSP ({', '.join(failed)} fails)."
        )
    return tau / MS


def to_nir(model: SNN6, height: int, width: int) -> Any:
    """The NIR graph of ``model`` for (C, ``height``, ``width``) input spikes (see module doc)."""
    nir = require_nir()
    nodes: dict[str, Any] = {
        "input": nir.Input(input_type=np.array([model.in_channels, height, width]))
    }
    edges: list[tuple[str, str]] = []
    previous = "input"
    channels, h, w = model.in_channels, height, width
    for index, conv in enumerate(model.convs, start=1):
        params = conv.current_params()  # learned time constants as they are now
        weight = conv.weight.detach().cpu().numpy().astype(np.float32)
        nodes[f"conv{index}"] = nir.Conv2d(
            input_shape=(h, w),
            weight=weight,
            stride=conv.stride,
            padding=0,
            dilation=1,
            groups=1,
            bias=np.zeros(weight.shape[0], dtype=np.float32),
        )
        h, w = conv.output_size(h, w)
        channels = weight.shape[0]
        nodes[f"lif{index}"] = nir.CubaLIF(
            **cubalif_parameters(params, (channels, h, w)),
            metadata={
                METADATA_KEY: {
                    "tau_r_ms": params.tau_r,
                    "scale_ref": params.scale_ref,
                    "scale_rho": params.scale_rho,
                }
            },
        )
        edges += [(previous, f"conv{index}"), (f"conv{index}", f"lif{index}")]
        previous = f"lif{index}"
    nodes["gasp"] = nir.AvgPool2d(
        kernel_size=np.array([h, w]), stride=np.array([h, w]), padding=np.array([0, 0])
    )
    # NIR shapes carry no batch axis: flatten (C, 1, 1) from its first axis.
    nodes["flatten"] = nir.Flatten(input_type={"input": np.array([channels, 1, 1])}, start_dim=0)
    nodes["fc"] = nir.Linear(weight=model.fc.weight.detach().cpu().numpy().astype(np.float32))
    nodes["readout"] = nir.CubaLI(**cubalif_parameters(model.fc.current_params(), (3,)))
    nodes["output"] = nir.Output(output_type=np.array([3]))
    edges += [
        (previous, "gasp"),
        ("gasp", "flatten"),
        ("flatten", "fc"),
        ("fc", "readout"),
        ("readout", "output"),
    ]
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata={METADATA_KEY: "SNN-6"}, type_check=True)


def _node(graph: Any, name: str, kind: type) -> Any:
    node = graph.nodes.get(name)
    if not isinstance(node, kind):
        found = type(node).__name__ if node is not None else "nothing"
        raise InputError(f"NIR graph: expected a {kind.__name__} node '{name}', found {found}.")
    return node


def _metadata_float(node: Any, key: str, default: float) -> float:
    meta = (node.metadata or {}).get(METADATA_KEY, {})
    return float(np.asarray(meta[key])) if key in meta else default


def from_nir(graph: Any) -> tuple[SNN6, tuple[int, int]]:
    """Rebuild SNN-6 from a graph written by :func:`to_nir`; returns (model, (height, width)).

    Exact for what the graph holds: convolution and readout weights, θ (which must equal
    SNN-6's, else InputError), τs, and τr and the refractory scale from the metadata (SNN-6's
    values where a foreign graph has none). Time constants other than SNN-6's come back as
    learned ones (``SNN6(learn_tau=True)``, inside its bounds). Surrogate-gradient settings
    are SNN-6's own.
    """
    nir = require_nir()
    shape = np.asarray(_node(graph, "input", nir.Input).input_type["input"])
    if shape.shape != (3,):
        raise InputError(f"NIR graph: input of shape {tuple(shape)}; SNN-6 takes (C, H, W).")
    channels, height, width = (int(v) for v in shape)
    taus = _time_constants(graph, nir)
    defaults = [(spec.params.tau_s, spec.params.tau_r) for spec in SNN6_LAYERS] + [
        (READOUT.tau_s, None)
    ]
    learned = any(
        not math.isclose(got, want, rel_tol=1e-6)
        for pair, default in zip(taus, defaults, strict=True)
        for got, want in zip(pair, default, strict=True)
        if want is not None
    )
    model = SNN6(in_channels=channels, learn_tau=learned)
    for index, (conv, spec) in enumerate(zip(model.convs, SNN6_LAYERS, strict=True), start=1):
        with torch.no_grad():
            conv.weight.copy_(torch.from_numpy(_conv_weight(graph, nir, index, conv, spec)))
    fc = np.asarray(_node(graph, "fc", nir.Linear).weight)
    if fc.shape != tuple(model.fc.weight.shape):
        raise InputError(
            f"NIR graph: readout of shape {fc.shape}; SNN-6 has {tuple(model.fc.weight.shape)}."
        )
    with torch.no_grad():
        model.fc.weight.copy_(torch.from_numpy(fc))
    if learned:
        for layer, (tau_s, tau_r) in zip((*model.convs, model.fc), taus, strict=True):
            layer.set_time_constants(tau_s, tau_r)
    if min(height, width) < model.min_input_size():
        raise InputError(f"NIR graph: input {width}x{height} px is smaller than SNN-6 accepts.")
    return model.eval(), (height, width)


def _conv_weight(graph: Any, nir: Any, index: int, conv: Any, spec: Any) -> np.ndarray:
    """The weight of node ``conv{index}``, checked against SNN-6's layer (shape, stride, no
    padding, no bias) and its neuron's threshold."""
    node = _node(graph, f"conv{index}", nir.Conv2d)
    weight = np.asarray(node.weight)
    if weight.shape != tuple(conv.weight.shape):
        raise InputError(
            f"NIR node 'conv{index}': weight of shape {weight.shape}, SNN-6 has "
            f"{tuple(conv.weight.shape)}."
        )
    stride = tuple(int(s) for s in np.atleast_1d(node.stride))
    if (
        set(stride) != {spec.stride}
        or np.any(np.asarray(node.padding) != 0)
        or np.any(np.asarray(node.bias) != 0)
    ):
        raise InputError(
            f"NIR node 'conv{index}': SNN-6 needs stride {spec.stride}, no padding, no bias."
        )
    theta = np.asarray(_node(graph, f"lif{index}", nir.CubaLIF).v_threshold)
    if not np.allclose(theta, spec.params.theta, rtol=1e-6):
        raise InputError(
            f"NIR node 'lif{index}': θ = {float(theta.flat[0]):g}; SNN-6's layer {index} has "
            f"θ = {spec.params.theta:g}."
        )
    return weight


def _time_constants(graph: Any, nir: Any) -> list[tuple[float, float | None]]:
    """(τs, τr) in ms of lif1 … lif5 and (τs, None) of the readout; τr from the metadata
    (SNN-6's where there is none). InputError where SNN-6 cannot hold them: another refractory
    scale, or a τ outside the bounds of learned time constants."""
    taus: list[tuple[float, float | None]] = []
    for index, spec in enumerate(SNN6_LAYERS, start=1):
        lif = _node(graph, f"lif{index}", nir.CubaLIF)
        tau_r = _metadata_float(lif, "tau_r_ms", spec.params.tau_r)
        scale_ref = _metadata_float(lif, "scale_ref", spec.params.scale_ref)
        if scale_ref != spec.params.scale_ref:
            raise InputError(
                f"NIR node 'lif{index}': refractory scale {scale_ref:g}; SNN-6 has "
                f"{spec.params.scale_ref:g}."
            )
        taus.append((srm_tau_ms(lif, f"lif{index}"), tau_r))
    taus.append((srm_tau_ms(_node(graph, "readout", nir.CubaLI), "readout"), None))
    for name, pair in zip([*(f"lif{i}" for i in range(1, 6)), "readout"], taus, strict=True):
        for tau in pair:
            if tau is not None and not TAU_MIN_MS < tau < TAU_MAX_MS:
                raise InputError(
                    f"NIR node '{name}': τ = {tau:g} ms; SNN-6 holds time constants in "
                    f"({TAU_MIN_MS:g}, {TAU_MAX_MS:g}) ms."
                )
    return taus


def export_nir(checkpoint: str | os.PathLike, out: str | os.PathLike) -> Path:
    """Write the SNN-6 of a spikegyro ``checkpoint`` as a NIR file ``out`` (HDF5); returns it.

    The input size is the checkpoint's sensor times its scale (what ``encode_window`` feeds).
    """
    nir = require_nir()
    payload = read_checkpoint(checkpoint, "CHECKPOINT")
    if payload["model"] != "snn6":
        raise InputError(
            f"{checkpoint}: a '{payload['model']}' checkpoint; only SNN-6 maps onto NIR neurons."
        )
    if payload["model_kwargs"].get("log_polar"):
        raise InputError(
            f"{checkpoint}: an SNN-6 with log-polar input channels; NIR has no node for the "
            "log-polar re-mapping, so only the plain network exports."
        )
    model = SNN6(**payload["model_kwargs"])
    model.load_state_dict(payload["state_dict"])
    spec = payload["input"]
    width, height = (round(side * float(spec.get("scale", 1.0))) for side in spec["sensor"])
    graph = to_nir(model, height, width)
    out = Path(out)
    with atomic_path(out) as tmp:
        nir.write(tmp, graph)
    return out


def read_nir(path: str | os.PathLike) -> tuple[SNN6, tuple[int, int]]:
    """:func:`from_nir` of a NIR file; errors name the file."""
    nir = require_nir()
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such NIR file.")
    try:
        graph = nir.read(path)
    except Exception as exc:  # h5py and nir raise many types for foreign files
        raise InputError(f"{path}: not a readable NIR file ({exc}).") from None
    try:
        return from_nir(graph)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
