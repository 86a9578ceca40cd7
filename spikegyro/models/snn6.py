"""SNN-6 of Gehrig et al. (ICRA 2020), layer for layer as the official model.

Architecture (Ts = 1 ms): five spiking 3×3 convolutions without padding or bias, channels
16-32-64-128-256, strides 2-2-2-2-1, then global average spike pooling (GASP), a dense 256→3
map without bias and a PSP with τs = 8 ms. Input (N, 2, H, W, T) spikes (channel 0 = OFF,
1 = ON); output (N, 3, T) angular velocity ω = (ω_x, ω_y, ω_z) in rad/s at every step.

Step-by-step semantics (what a stateful, streaming implementation must reproduce; ε and ν are
the layer's ``srm_kernel`` and ``ref_kernel`` buffers, see :mod:`spikegyro.snn.kernels` for their
truncation: ε stops at the first k > τs with ε[k] < 0.01, ν keeps the taps with |ν[k]| > 0.01),
for layer l = 1…5 at step t, with s_0 the input and all history before t = 0 zero:

    z_l[t] = conv2d(s_{l−1}[t], W_l, stride_l)                (no padding, no bias)
    v_l[t] = Σ_{k=0}^{len(ε)−1} ε_l[k] · z_l[t − k]           (PSP; ε[0] = 0)
    u_l[t] = v_l[t] + Σ_{k=1}^{len(ν)−1} ν_l[k] · s_l[t − k]  (refractory feedback, own spikes)
    s_l[t] = 1 if u_l[t] ≥ θ_l else 0

then m[t] = mean over (h, w) of s_5[t] (N, 256); y[t] = W_fc · m[t] (N, 3);
ω[t] = Σ_k ε_8[k]·y[t − k].
The official code filters before convolving (conv2d(psp(s))); both maps are linear, so the two
orders are equal up to float rounding, and :class:`spikegyro.snn.layers.SRMConv` filters on
whichever side has fewer neurons. The batch implementation sums the PSP in a matrix product, so
a step-by-step one agrees to ~1e-6 and can differ in a spike only where u is within rounding
of θ. Inputs must be at least 63x63 px (layer 5 then has a 1x1 map); 240x180 gives 12x8 maps at
layer 5, 120x90 gives 4x2. The spikes of :meth:`SNN6.forward_with_spikes` are (N, C, H, W, T)
views of time-major, channels-last storage.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import nn

from spikegyro.errors import InputError
from spikegyro.events.representations import (
    LOG_POLAR_R_MIN,
    log_polar_pixel_map,
    log_polar_spikes,
)
from spikegyro.models.registry import register
from spikegyro.snn.layers import GASP, RegionPool, SRMConv, SRMDense, SRMParams
from spikegyro.snn.sparse import EventDrivenStack


@dataclass(frozen=True)
class ConvSpec:
    """One spiking conv layer of SNN-6."""

    out_channels: int
    stride: int
    params: SRMParams


SNN6_LAYERS: tuple[ConvSpec, ...] = (
    ConvSpec(16, 2, SRMParams(tau_s=2.0, theta=0.27, tau_r=1.0, scale_rho=0.20)),
    ConvSpec(32, 2, SRMParams(tau_s=2.0, theta=0.25, tau_r=1.0, scale_rho=0.13)),
    ConvSpec(64, 2, SRMParams(tau_s=4.0, theta=0.30, tau_r=4.0, scale_rho=0.13)),
    ConvSpec(128, 2, SRMParams(tau_s=4.0, theta=0.40, tau_r=4.0, scale_rho=0.25)),
    ConvSpec(256, 1, SRMParams(tau_s=4.0, theta=0.40, tau_r=4.0, scale_rho=100.0)),
)
"""Per-layer values of the official model (θ, τs, τr in ms, scaleRho; tauRho = 0.3)."""

READOUT = SRMParams(tau_s=8.0)
"""Non-spiking readout: PSP with τs = 8 ms of the dense layer's output."""

KERNEL_SIZE = 3


def scaled_taus(params: SRMParams, factor: float) -> SRMParams:
    """``params`` with τs and τr (ms) multiplied by ``factor`` (a longer memory)."""
    if factor == 1.0:
        return params
    return replace(params, tau_s=params.tau_s * factor, tau_r=params.tau_r * factor)


INIT_GAIN = 1.5
"""Weight init: uniform in ±INIT_GAIN/√fan_in per layer (1.0 is PyTorch's and the official
default). At 1.0, uniform random input spikes at 1 % density leave layer 5 silent, and a silent
network has no gradient. At 1.5 (240x180, T = 100) layers 1-5 fire on 0.7/1.9/5/8/11 % of
(neuron, step) pairs at 0.3 % input density, 2.6/9/18/23/26 % at 1 % and stay alive at 2 %."""


@register("snn6")
class SNN6(nn.Module):
    """The paper's spiking network; see the module docstring for the exact computation.

    Args:
        in_channels: input polarity channels (2).
        init_gain: weight init scale, uniform in ±init_gain/√fan_in per layer.
        readout_grid: (rows, columns) of the spike pooling before the dense readout; (1, 1) is
            the paper's global average spike pooling (GASP).
        log_polar: also feed conv1 the input re-mapped to a log-polar grid of the same size
            around ``log_polar_centre`` (channels ``in_channels`` … ``2·in_channels − 1``; see
            :func:`spikegyro.events.representations.log_polar_coordinates`): there a roll is a
            horizontal translation of the same size at every radius, also near the centre.
        log_polar_centre: (cx, cy) of the log-polar grid in input pixels; None: (W/2, H/2), the
            simulator's principal point (exact at scale 1, a quarter pixel off at scale 0.5).
        log_polar_r_min: inner radius of the log-polar grid, input pixels.
        log_polar_share: used only when :func:`adapt_state` fits a Cartesian network to this
            one (``train --init``): the share of conv1's weights that starts on the log-polar
            channels (Cartesian weights times 1 − share, their copy times share). 0 keeps the
            source network's output exactly but leaves the branch to grow from zero.
        tau_scale: factor on τs and τr of every spiking layer (a longer memory; 1 = the paper).
        readout_tau: τs of the readout's PSP, ms (8 = the paper).
        learn_tau: train τs and τr of every spiking layer and τs of the readout (from the
            values above), on the batch path and the event-driven engine alike; checkpoints
            carry them (see :meth:`time_constants`, :meth:`tau_parameters`).
    """

    def __init__(
        self,
        in_channels: int = 2,
        init_gain: float = INIT_GAIN,
        readout_grid: tuple[int, int] = (1, 1),
        log_polar: bool = False,
        log_polar_centre: tuple[float, float] | None = None,
        log_polar_r_min: float = LOG_POLAR_R_MIN,
        log_polar_share: float = 0.0,
        tau_scale: float = 1.0,
        readout_tau: float = READOUT.tau_s,
        learn_tau: bool = False,
    ) -> None:
        super().__init__()
        if not (tau_scale > 0 and readout_tau > 0):
            raise InputError(
                f"SNN-6 with tau_scale {tau_scale}, readout_tau {readout_tau}: both must be > 0."
            )
        if not 0.0 <= log_polar_share <= 1.0:
            raise InputError(f"SNN-6 with log_polar_share {log_polar_share}: use 0 … 1.")
        self.in_channels = in_channels
        self.readout_grid = (int(readout_grid[0]), int(readout_grid[1]))
        self.log_polar = bool(log_polar)
        self.log_polar_centre = None if log_polar_centre is None else tuple(log_polar_centre)
        self.log_polar_r_min = float(log_polar_r_min)
        self.log_polar_share = float(log_polar_share)
        self.learn_tau = bool(learn_tau)
        self._pixel_maps: dict[tuple[int, int], torch.Tensor] = {}
        # The log-polar copy of the input enters conv1 as extra channels.
        channels = in_channels * (2 if self.log_polar else 1)
        convs = []
        for i, spec in enumerate(SNN6_LAYERS):
            # Layers 2-5 see the spikes of the layer before; the input may hold event counts.
            convs.append(
                SRMConv(
                    channels,
                    spec.out_channels,
                    scaled_taus(spec.params, tau_scale),
                    KERNEL_SIZE,
                    spec.stride,
                    binary_input=i > 0,
                    learn_tau=self.learn_tau,
                )
            )
            channels = spec.out_channels
        # Named conv1 … conv5 and fc, as in the official state dict.
        self.conv1, self.conv2, self.conv3, self.conv4, self.conv5 = convs
        cells = self.readout_grid[0] * self.readout_grid[1]
        self.pool = GASP() if cells == 1 else RegionPool(self.readout_grid)
        readout = replace(READOUT, tau_s=float(readout_tau))
        self.fc = SRMDense(channels * cells, 3, readout, learn_tau=self.learn_tau)
        self.reset_parameters(init_gain)

    @property
    def convs(self) -> tuple[SRMConv, ...]:
        return (self.conv1, self.conv2, self.conv3, self.conv4, self.conv5)

    def freeze(self, layers: int) -> list[nn.Parameter]:
        """Keep the weights of conv1 … conv``layers`` fixed; returns the parameters still trained.

        Frozen layers build no autograd graph, so a step costs about half as much (with
        ``layers=4`` on the CPU: 0.49x, ``bench/snn_step.py --impls spikegyro spikegyro-freeze4``),
        and fine-tuning the last layers fits a CPU's budget.
        """
        for i, conv in enumerate(self.convs):
            conv.requires_grad_(i >= layers)
        return [p for p in self.parameters() if p.requires_grad]

    def time_constants(self) -> dict[str, dict[str, float]]:
        """Current τs and τr (ms) per layer: {"conv1": {"tau_s": …, "tau_r": …}, …,
        "fc": {"tau_s": …}} (learned or fixed)."""
        out = {}
        for name in (*(f"conv{i + 1}" for i in range(len(self.convs))), "fc"):
            p = getattr(self, name).current_params()
            out[name] = {"tau_s": p.tau_s, **({"tau_r": p.tau_r} if p.spiking else {})}
        return out

    def tau_parameters(self) -> list[nn.Parameter]:
        """The parameters that hold the learned time constants (empty unless ``learn_tau``),
        e.g. for an optimizer group of their own."""
        return [
            p
            for name, p in self.named_parameters()
            if name.endswith(("tau_s_param", "tau_r_param"))
        ]

    def set_surrogate_cut(self, cut: float) -> None:
        """Bound the surrogate gradient of every spiking layer: ρ = 0 where the spike pdf falls
        below ``cut`` times its peak (0 = SLAYER's unbounded pdf; see
        :func:`spikegyro.snn.functional.surrogate_half_width`). Changes gradients only."""
        for conv in self.convs:
            conv.params = replace(conv.params, rho_cut=float(cut))

    def use_event_engine(self, threads: int | None) -> None:
        """Run the spiking layers with the event-driven CPU engine (``threads`` batch elements
        at once, :mod:`spikegyro.snn.sparse`), or with the batch torch path (``None``, the
        default). Same weights and checkpoints; with a bounded surrogate
        (:meth:`set_surrogate_cut`) the same gradients, much faster on a CPU."""
        self._engine = None if threads is None else EventDrivenStack(self.convs, self.pool, threads)

    @property
    def event_engine(self) -> EventDrivenStack | None:
        """The event-driven engine in use, or None (the batch path)."""
        return getattr(self, "_engine", None)

    def reset_parameters(self, gain: float = INIT_GAIN) -> None:
        """Re-draw all weights uniformly in ±gain/√fan_in."""
        for layer in (*self.convs, self.fc):
            layer.reset_parameters(gain)

    def feature_size(self, height: int, width: int) -> tuple[int, int]:
        """Spatial size (px) of the layer-5 map for a height × width input."""
        for conv in self.convs:
            height, width = conv.output_size(height, width)
        return height, width

    def min_input_size(self) -> int:
        """Smallest input side (px) for which layer 5 still has one neuron per channel."""
        side = 1
        for conv in reversed(self.convs):
            side = (side - 1) * conv.stride + conv.weight.shape[-1] - 2 * conv.padding
        return side

    def _check_input(self, x: torch.Tensor) -> None:
        if x.dim() != 5 or x.shape[1] != self.in_channels:
            raise InputError(
                f"SNN-6 input of shape {tuple(x.shape)}: expected (N, {self.in_channels}, H, W, T) "
                "spikes; add a batch dimension or fix the channel count."
            )
        height, width = x.shape[2:4]
        side = self.min_input_size()
        if min(height, width) < side:
            raise InputError(
                f"SNN-6 input of {width}x{height} px is too small: the network needs at least "
                f"{side}x{side} px (5 unpadded 3x3 convolutions); use a larger sensor or scale."
            )

    def with_log_polar(self, spikes: torch.Tensor) -> torch.Tensor:
        """The network's conv1 input: the spikes, plus their log-polar copy when the model has
        one, (N, C, H, W, T) -> (N, 2C, H, W, T) in time-major storage like the input."""
        if not self.log_polar:
            return spikes
        height, width = spikes.shape[2:4]
        key = (height, width)
        if key not in self._pixel_maps:
            centre = self.log_polar_centre or (width / 2, height / 2)
            self._pixel_maps[key] = log_polar_pixel_map(height, width, centre, self.log_polar_r_min)
        time_major = spikes.permute(4, 0, 1, 2, 3)  # (T, N, C, H, W), a view of the storage
        mapped = log_polar_spikes(time_major, self._pixel_maps[key], spatial_dim=3)
        return torch.cat([time_major, mapped], dim=2).permute(1, 2, 3, 4, 0)

    def _run(self, x: torch.Tensor, keep_spikes: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        self._check_input(x)
        spikes = x if x.is_floating_point() else x.to(self.fc.weight.dtype)
        engine = self.event_engine
        events = engine is not None and not keep_spikes and x.device.type == "cpu"
        if spikes.is_sparse and (self.log_polar or not events):
            spikes = spikes.to_dense()  # the batch path and the log-polar map need it dense
        spikes = self.with_log_polar(spikes)
        if events:
            return self.fc(engine.pooled(spikes)), []
        per_layer = []
        for conv in self.convs:
            spikes = conv(spikes)
            if keep_spikes:  # otherwise each layer's spikes are freed as soon as possible
                per_layer.append(spikes)
        return self.fc(self.pool(spikes)), per_layer

    def forward_with_spikes(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Run the network; returns (ω (N, 3, T) rad/s, [spikes (N, C, H, W, T) of layers 1–5])."""
        return self._run(x, keep_spikes=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """ω (N, 3, T) in rad/s from input spikes (N, 2, H, W, T), dense or sparse COO."""
        return self._run(x, keep_spikes=False)[0]


@register("snn6-grid")
def snn6_grid(
    in_channels: int = 2,
    init_gain: float = INIT_GAIN,
    grid: tuple[int, int] = (2, 3),
    **options: Any,
) -> SNN6:
    """SNN-6 whose readout pools layer 5 per cell of a coarse grid instead of globally.

    A test of the hypothesis in docs/evaluation.md ("Real recordings"): GASP hides where a feature
    fired, and roll's flow field depends on position. At 240x180, layer 5 is 12x8, so the
    default 2x3 grid has cells of 4x4 neurons; at 120x90 (4x2) use a grid of (2, 2).
    ``options``: the other :class:`SNN6` arguments (log_polar, tau_scale, ...).
    """
    return SNN6(in_channels, init_gain, readout_grid=grid, **options)


def grid_state_from_global(
    state: dict[str, torch.Tensor], grid: tuple[int, int]
) -> dict[str, torch.Tensor]:
    """The state dict of an ``snn6-grid`` network that computes exactly what the GASP network
    with ``state`` does: the start point for training the grid readout (``train --init``).

    The conv weights are kept; each cell's readout weights are the global ones divided by the
    number of cells, so when the cells are equal in size (a grid dividing the layer-5 map) the
    sum over cells is the global mean.
    """
    if state["fc.weight"].shape[1] != SNN6_LAYERS[-1].out_channels:
        raise InputError("grid_state_from_global: the network already pools on a grid.")
    cells = grid[0] * grid[1]
    return {**state, "fc.weight": state["fc.weight"].repeat_interleave(cells, dim=1) / cells}


def _kernel_area(kernel: torch.Tensor) -> float:
    """Sum of a PSP kernel's taps: the potential a steady input of one spike per ms builds."""
    return float(kernel.double().sum())


def adapt_state(state: dict[str, torch.Tensor], model: SNN6) -> dict[str, torch.Tensor]:
    """A state dict of another SNN-6 variant made to fit ``model``, computing (nearly) what the
    source network computes: the start point of ``train --init`` across variants.

    - GASP -> grid readout: :func:`grid_state_from_global` (exact for a grid dividing layer 5).
    - More conv1 input channels (the log-polar copy): the extra channels get the source's conv1
      weights times ``model.log_polar_share`` and the source's own channels keep 1 − share of
      theirs; at share 0 (the default) the output is unchanged until training moves them.
    - Other time constants (``tau_scale``, ``readout_tau``): the model keeps its own kernels and
      each layer's weights are multiplied by (source kernel area / new kernel area), which keeps
      the potential a steady input rate builds (the response to a single spike changes).
    - Learned time constants (``learn_tau``): a model that learns τ takes the source's learned τ
      and kernels as they are, or starts its τ from its own values (the rule above) when the
      source's are fixed; a model with fixed τ drops a source's learned τ (the rule above).
    """
    state = dict(state)
    if model.readout_grid != (1, 1) and state["fc.weight"].shape[1] != model.fc.weight.shape[1]:
        state = grid_state_from_global(state, model.readout_grid)
    weight = state["conv1.weight"]
    extra = model.conv1.weight.shape[1] - weight.shape[1]
    if extra == weight.shape[1]:  # the log-polar copy of every input channel
        share = model.log_polar_share
        state["conv1.weight"] = torch.cat([weight * (1.0 - share), weight * share], dim=1)
    elif extra > 0:
        zeros = weight.new_zeros(weight.shape[0], extra, *weight.shape[2:])
        state["conv1.weight"] = torch.cat([weight, zeros], dim=1)
    layers = [(f"conv{i + 1}", conv) for i, conv in enumerate(model.convs)] + [("fc", model.fc)]
    for name, layer in layers:
        own_taus = {k: v for k, v in layer.named_parameters() if k.startswith("tau_")}
        if own_taus and all(f"{name}.{k}" in state for k in own_taus):
            continue  # a source with learned τ: its τ and the kernels they give
        for key in (f"{name}.tau_s_param", f"{name}.tau_r_param"):
            state.pop(key, None)
        state.update({f"{name}.{k}": v.detach().clone() for k, v in own_taus.items()})
        own = layer.srm_kernel
        stored = state.get(f"{name}.srm_kernel")
        if stored is not None and (stored.shape != own.shape or not torch.equal(stored, own)):
            ratio = _kernel_area(stored) / _kernel_area(own)
            state[f"{name}.weight"] = state[f"{name}.weight"] * ratio
        for buffer in ("srm_kernel", "ref_kernel"):
            if hasattr(layer, buffer):
                state[f"{name}.{buffer}"] = getattr(layer, buffer).detach().clone()
    return state
