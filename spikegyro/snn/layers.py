"""SRM spiking layers (thin modules over :mod:`spikegyro.snn.functional`).

Tensor layout: spike trains are ``(N, C, H, W, T)`` for conv layers and ``(N, C, T)`` for dense
ones, time last in 1 ms steps, as in SLAYER and the official code. Every layer returns a tensor
whose *storage* is time-major (a permuted view): the next layer folds time into the batch and
filters along time without copying.

A layer computes s_out = spike(conv(psp(s_in))) like the official model. Convolution (over
space) and PSP (over time) are linear and commute, so a conv layer filters on the side with fewer
neurons (for SNN-6 at 240x180: the input of layers 1 and 5, the output of layers 2-4, where the
convolution then sees 0/1 spikes and can keep them for the backward pass as booleans).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import torch
from torch import nn

from spikegyro.snn.functional import TAU_RHO, conv_over_time, psp, spike_fn
from spikegyro.snn.kernels import (
    param_from_tau,
    refractory_kernel,
    refractory_kernel_of,
    srm_kernel,
    srm_kernel_of,
    tau_from_param,
)


@dataclass(frozen=True)
class SRMParams:
    """Neuron parameters of one layer (times in ms, potentials in weight units).

    Attributes:
        tau_s: synaptic time constant τs of the PSP kernel ε.
        theta: threshold θ; ``None`` makes a non-spiking layer whose output is the PSP itself.
        tau_r: refractory time constant τr of ν.
        scale_rho: surrogate height (SLAYER's scaleRho); tau_rho: its width relative to θ.
        scale_ref: refractory depth relative to θ (ν[1] = −scale_ref·θ).
        rho_cut: bound of the surrogate's support, as a share of its peak (0 = unbounded, SLAYER's;
            see :func:`spikegyro.snn.functional.surrogate_half_width`).
    """

    tau_s: float
    theta: float | None = None
    tau_r: float = 1.0
    scale_rho: float = 1.0
    tau_rho: float = TAU_RHO
    scale_ref: float = 2.0
    rho_cut: float = 0.0

    @property
    def spiking(self) -> bool:
        return self.theta is not None


class _SRMLayer(nn.Module):
    """Weights plus the layer's kernels as buffers (saved in checkpoints, replaceable on load).

    With ``learn_tau`` the time constants τs (and τr of a spiking layer) are trainable:
    parameters ``tau_s_param`` and ``tau_r_param`` hold ρ with τ = ``tau_from_param(ρ)`` ms
    (:func:`spikegyro.snn.kernels.tau_from_param`: bounded, smooth), the kernels follow them
    in every forward pass (differentiably; their lengths by the truncation rule) and the
    buffers ``srm_kernel``/``ref_kernel`` hold a copy of the kernels at the current τ, of the
    length those need, for checkpoints and for the streaming engine. ``params`` keeps the
    initial values.
    """

    def __init__(
        self, params: SRMParams, weight_shape: tuple[int, ...], learn_tau: bool = False
    ) -> None:
        super().__init__()
        self.params = params
        self.learn_tau = bool(learn_tau)
        self.weight = nn.Parameter(torch.empty(weight_shape))
        if self.learn_tau:
            self.tau_s_param = nn.Parameter(torch.tensor(param_from_tau(params.tau_s)))
            if params.spiking:
                self.tau_r_param = nn.Parameter(torch.tensor(param_from_tau(params.tau_r)))
        for name, kernel in self._kernels(torch.float32).items():
            self.register_buffer(name, kernel)
        self.reset_parameters()

    def _kernels(self, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        p = self.current_params()
        kernels = {"srm_kernel": srm_kernel(p.tau_s, dtype=dtype)}
        if p.spiking:
            kernels["ref_kernel"] = refractory_kernel(
                p.theta, p.tau_r, scale_ref=p.scale_ref, dtype=dtype
            )
        return kernels

    def tau_s(self) -> torch.Tensor:
        """τs (ms), a 0-dim float64 tensor: differentiable in ``tau_s_param`` when learned
        (the kernels are computed in float64 and then cast, as the fixed ones are)."""
        if self.learn_tau:
            return tau_from_param(self.tau_s_param.double())
        return torch.tensor(self.params.tau_s, dtype=torch.float64)

    def tau_r(self) -> torch.Tensor:
        """τr (ms) of a spiking layer, a 0-dim float64 tensor (see :meth:`tau_s`)."""
        if self.learn_tau:
            return tau_from_param(self.tau_r_param.double())
        return torch.tensor(self.params.tau_r, dtype=torch.float64)

    def current_params(self) -> SRMParams:
        """``params`` with the current (learned) τs and τr, in ms."""
        if not self.learn_tau:
            return self.params
        tau_r = float(self.tau_r().detach()) if self.params.spiking else self.params.tau_r
        return replace(self.params, tau_s=float(self.tau_s().detach()), tau_r=tau_r)

    def set_time_constants(self, tau_s: float, tau_r: float | None = None) -> None:
        """Set the learned τs (and τr), ms, inside the bounds of :func:`param_from_tau`."""
        if not self.learn_tau:
            raise ValueError("set_time_constants: this layer's time constants are fixed")
        with torch.no_grad():
            self.tau_s_param.fill_(param_from_tau(tau_s))
            if tau_r is not None and self.params.spiking:
                self.tau_r_param.fill_(param_from_tau(tau_r))
        self.refresh_kernels()

    def current_kernels(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(ε, ν or None) at the current τ: from the learned τ in the weight's dtype, on the
        graph of ``tau_*_param`` (and copied into the buffers), else the buffers."""
        if not self.learn_tau:
            return self.srm_kernel, getattr(self, "ref_kernel", None)
        dtype = self.weight.dtype
        srm = srm_kernel_of(self.tau_s()).to(dtype)
        ref = None
        if self.params.spiking:
            p = self.params
            ref = refractory_kernel_of(p.theta, self.tau_r(), scale_ref=p.scale_ref).to(dtype)
        self.srm_kernel = srm.detach().clone()
        if ref is not None:
            self.ref_kernel = ref.detach().clone()
        return srm, ref

    @torch.no_grad()
    def refresh_kernels(self) -> None:
        """Bring the kernel buffers to the current learned τ (a no-op for fixed ones)."""
        if self.learn_tau:
            self.current_kernels()

    def _save_to_state_dict(self, destination, prefix, keep_vars) -> None:
        self.refresh_kernels()  # an optimizer step since the last forward moved τ
        super()._save_to_state_dict(destination, prefix, keep_vars)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        if self.learn_tau:  # the stored kernels have the lengths of the stored τ
            for name in ("srm_kernel", "ref_kernel"):
                stored, own = state_dict.get(prefix + name), getattr(self, name, None)
                if stored is not None and own is not None and stored.shape != own.shape:
                    setattr(self, name, own.new_empty(stored.shape))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def exact_kernels(self) -> None:
        """Recompute the kernels from the parameters, in the weight's dtype and on its device.

        ``.double()`` only widens the float32 taps, which keep their rounding (≤ 6e-8 relative);
        a float64 forward with exact taps (call this after ``.double()``) is the reference that
        the streaming engine, which runs the kernels as exact recursions, reproduces to the last
        bits. Learned kernels are computed in the weight's dtype at every forward pass anyway.
        """
        for name, kernel in self._kernels(torch.float64).items():
            setattr(self, name, kernel.to(self.weight))

    def reset_parameters(self, gain: float = 1.0) -> None:
        """Uniform weights in ±gain/√fan_in (PyTorch's default conv init when gain = 1)."""
        fan_in = math.prod(self.weight.shape[1:])
        bound = gain / math.sqrt(fan_in)
        with torch.no_grad():
            self.weight.uniform_(-bound, bound)

    def _fire(self, potential: torch.Tensor, ref_kernel: torch.Tensor | None) -> torch.Tensor:
        """Spikes of a time-major (T, …) potential (the potential itself when non-spiking).

        The potential is an intermediate of this layer, so its storage is reused.
        """
        if not self.params.spiking:
            return potential
        p = self.params
        return spike_fn(
            potential, p.theta, ref_kernel, p.scale_rho, p.tau_rho, dim=0, overwrite=True,
            cut=p.rho_cut,
        )  # fmt: skip


class SRMConv(_SRMLayer):
    """Spiking 2-D convolution, no bias: (N, C_in, H, W, T) → (N, C_out, H', W', T).

    ``binary_input=True`` promises 0/1 input (e.g. the spikes of another SRM layer), which then
    is kept for the backward pass as booleans; leave it False for graded input such as counts.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        params: SRMParams,
        kernel_size: int = 3,
        stride: int = 1,
        padding: int = 0,
        binary_input: bool = False,
        learn_tau: bool = False,
    ) -> None:
        self.stride = stride
        self.padding = padding
        self.binary_input = binary_input
        shape = (out_channels, in_channels, kernel_size, kernel_size)
        super().__init__(params, shape, learn_tau)

    def output_size(self, height: int, width: int) -> tuple[int, int]:
        """Spatial size (px) of the output map for an input of ``height`` × ``width`` px."""
        k = self.weight.shape[-1]

        def size(n: int) -> int:
            return (n + 2 * self.padding - k) // self.stride + 1

        return size(height), size(width)

    def forward(self, spikes: torch.Tensor) -> torch.Tensor:
        x = spikes.permute(4, 0, 1, 2, 3)  # (T, N, C, H, W): a view for time-major storage
        channels, height, width = x.shape[2:]
        out_height, out_width = self.output_size(height, width)
        conv = functools.partial(
            conv_over_time, weight=self.weight, stride=self.stride, padding=self.padding
        )
        srm, ref = self.current_kernels()
        # PSP and convolution commute: filter on whichever side has fewer neurons. On the
        # input of layer 1 this also skips the PSP's backward pass (the input needs no gradient).
        if channels * height * width <= self.weight.shape[0] * out_height * out_width:
            potential = conv(psp(x, srm, dim=0))
        else:
            potential = psp(conv(x, binary=self.binary_input), srm, dim=0)
        return self._fire(potential, ref).permute(1, 2, 3, 4, 0)


class SRMDense(_SRMLayer):
    """Fully connected SRM layer, no bias: (N, C_in, T) → (N, C_out, T).

    With ``params.theta = None`` it is the non-spiking readout: the PSP of the weighted input.
    """

    def __init__(
        self, in_features: int, out_features: int, params: SRMParams, learn_tau: bool = False
    ) -> None:
        super().__init__(params, (out_features, in_features), learn_tau)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        current = torch.nn.functional.linear(x.permute(2, 0, 1), self.weight)
        srm, ref = self.current_kernels()
        return self._fire(psp(current, srm, dim=0), ref).permute(1, 2, 0)


class GASP(nn.Module):
    """Global average spike pooling: spatial mean at each step, (N, C, H, W, T) → (N, C, T)."""

    def forward(self, spikes: torch.Tensor) -> torch.Tensor:
        return spikes.mean(dim=(2, 3))


class RegionPool(nn.Module):
    """Average spike pooling per cell of a coarse grid: (N, C, H, W, T) → (N, C·gh·gw, T).

    Feature ``c·gh·gw + i·gw + j`` is channel c's mean over grid cell (i, j) (rows top to
    bottom, columns left to right; cells as :func:`torch.nn.functional.adaptive_avg_pool2d`
    cuts them). A (1, 1) grid is :class:`GASP`. Unlike GASP, the readout then knows roughly
    *where* a feature fired, which rotation about the optical axis (roll) needs: its flow turns
    with the position in the image.
    """

    def __init__(self, grid: tuple[int, int]) -> None:
        super().__init__()
        self.grid = (int(grid[0]), int(grid[1]))

    def forward(self, spikes: torch.Tensor) -> torch.Tensor:
        n, c, h, w, t = spikes.shape
        frames = spikes.permute(0, 1, 4, 2, 3).reshape(n, c * t, h, w)
        cells = nn.functional.adaptive_avg_pool2d(frames, self.grid)
        return cells.reshape(n, c, t, -1).permute(0, 1, 3, 2).reshape(n, -1, t)
