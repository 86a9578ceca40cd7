"""Pure functions of SRM spiking layers: PSP filtering, spiking with refractoriness, surrogate.

Units: one time step is Ts = 1 ms; potentials and thresholds are in the (dimensionless) units of
the weights; spikes are 0/1 per step (SLAYER's 1/Ts with Ts = 1).

Layout: every function takes the axis that holds time as ``dim`` (default: last, the official
SLAYER layout ``(N, C, H, W, T)``). Internally time is brought to the front as a ``(T, M)``
matrix, M = all other axes: the PSP is one banded-Toeplitz matrix product over all neurons, and
the spike recursion walks the T rows with whole-row operations. Tensors whose storage is already
time-major (e.g. ``(T, N, C, H, W)`` permuted to look time-last) pass through without a copy; the
layers in :mod:`spikegyro.snn.layers` keep their data that way.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import os
from collections.abc import Iterator
from types import ModuleType

import torch
import torch.nn.functional as F

TAU_RHO = 0.3
"""Default width of the surrogate spike pdf, relative to θ (SLAYER's tauRho)."""

_PARALLEL_GRAIN = 32768
"""PyTorch runs element-wise CPU operations on fewer elements than this on one thread."""

_BLOCK_STEPS = 128
"""PSP block length (steps): windows up to this long take one matrix product; longer ones are
cut into blocks so the cost grows linearly with T."""


@functools.cache
def _triton_module() -> ModuleType | None:
    """:mod:`spikegyro.snn.triton_kernels`, or None where Triton is not installed."""
    try:
        return importlib.import_module("spikegyro.snn.triton_kernels")
    except ImportError:
        return None


def _fused(x: torch.Tensor, ref_kernel: torch.Tensor | None = None) -> ModuleType | None:
    """The Triton kernels when they handle ``x`` (float32 on CUDA, or any tensor under Triton's
    interpreter), else None: then the torch code below runs."""
    if not (x.is_cuda or os.environ.get("TRITON_INTERPRET", "0") == "1"):
        return None  # the CPU path never imports Triton
    module = _triton_module()
    return module if module is not None and module.enabled_for(x, ref_kernel) else None


class _TimeRows:
    """A (T, M) matrix view of a tensor, time along the rows, and the way back.

    When the time axis has the largest stride and the other axes are dense (time-major storage
    in any order, e.g. channels-last), the rows are a view of the storage. Time-last storage is
    viewed as the transpose of a (M, T) matrix, which matmul reads without a copy. Anything else
    is copied once.
    """

    def __init__(self, x: torch.Tensor, dim: int) -> None:
        time_first = x.movedim(dim, 0)
        # Order the other axes by stride: a time-major tensor then reads as a plain block.
        order = sorted(range(1, x.dim()), key=lambda d: -time_first.stride(d))
        ordered = time_first.permute(0, *order)
        self.dim = dim
        if ordered.is_contiguous():
            self.order = [0, *order]
            self.rows = ordered.reshape(ordered.shape[0], -1)
        else:
            self.order = list(range(x.dim()))
            steps = time_first.shape[0]
            self.rows = x.movedim(dim, -1).reshape(-1, steps).t()
        self.shape = time_first.permute(*self.order).shape

    def back(self, rows: torch.Tensor) -> torch.Tensor:
        """View a (T, M) result in the same row layout with the original shape and axis order."""
        inverse = sorted(range(len(self.order)), key=self.order.__getitem__)
        return rows.reshape(self.shape).permute(*inverse).movedim(0, self.dim)


def _toeplitz(kernel: torch.Tensor, size: int) -> torch.Tensor:
    """(size, size) matrix W[i, j] = kernel[i − j] where 0 ≤ i − j < len(kernel), else 0."""
    steps = torch.arange(size, device=kernel.device)
    lag = steps[:, None] - steps[None, :]
    valid = (lag >= 0) & (lag < kernel.numel())
    return torch.where(valid, kernel[lag.clamp(0, kernel.numel() - 1)], kernel.new_zeros(()))


def _causal_filter(rows: torch.Tensor, kernel: torch.Tensor, *, adjoint: bool) -> torch.Tensor:
    """y[t] = Σ_k kernel[k]·x[t − k] (causal) or its adjoint y[t] = Σ_k kernel[k]·x[t + k].

    ``rows`` is (T, M); the result is a new contiguous (T, M) tensor. Blocks of ``block`` output
    steps only see their own and one neighbouring block of input, since block ≥ len(kernel).
    """
    steps = rows.shape[0]
    kernel = kernel.to(device=rows.device, dtype=rows.dtype)
    out = torch.empty(rows.shape, dtype=rows.dtype, device=rows.device)
    if rows.numel() == 0:
        return out
    block = max(_BLOCK_STEPS, kernel.numel())
    band = _toeplitz(kernel, min(steps, 2 * block))
    for b0 in range(0, steps, block):
        b1 = min(b0 + block, steps)
        if adjoint:
            end = min(steps, b1 + block)
            torch.matmul(band[: end - b0, : b1 - b0].t(), rows[b0:end], out=out[b0:b1])
        else:
            start = max(0, b0 - block)
            torch.matmul(
                band[b0 - start : b1 - start, : b1 - start], rows[start:b1], out=out[b0:b1]
            )
    return out


def kernel_gradient(grad: torch.Tensor, rows: torch.Tensor, taps: int) -> torch.Tensor:
    """g[k] = Σ_t Σ_m grad[t, m]·rows[t − k, m] for 0 ≤ k < ``taps``: the gradient wrt the taps
    of a causal filter y = kernel * rows (along the T rows of the (T, M) matrices) given ∂L/∂y.

    Blocks of output steps take one matrix product with the input steps that reach them, whose
    diagonals are then summed per lag: the cost of the forward filter, once.
    """
    steps = rows.shape[0]
    out = torch.zeros(taps, dtype=grad.dtype, device=grad.device)
    if rows.numel() == 0:
        return out
    block = max(_BLOCK_STEPS, taps)
    for b0 in range(0, steps, block):
        b1 = min(b0 + block, steps)
        start = max(0, b0 - taps + 1)
        products = torch.matmul(grad[b0:b1], rows[start:b1].t())
        lag = (
            torch.arange(b0, b1, device=grad.device)[:, None]
            - torch.arange(start, b1, device=grad.device)[None, :]
        )
        valid = (lag >= 0) & (lag < taps)
        out.index_add_(0, lag[valid], products[valid])
    return out


class _PSPFunction(torch.autograd.Function):
    """Causal filtering along rows; the backward pass is the exact adjoint (a correlation), and
    the kernel's gradient where it is asked for (learned time constants)."""

    @staticmethod
    def forward(ctx, rows: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(kernel, rows if kernel.requires_grad else None)
        return _causal_filter(rows, kernel, adjoint=False)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        kernel, rows = ctx.saved_tensors
        grad_rows = _causal_filter(grad, kernel, adjoint=True) if ctx.needs_input_grad[0] else None
        grad_kernel = None
        if ctx.needs_input_grad[1]:
            grad_kernel = kernel_gradient(grad, rows, kernel.numel()).to(kernel.dtype)
        return grad_rows, grad_kernel


def psp(x: torch.Tensor, kernel: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Post-synaptic potential: causal convolution of ``x`` with ``kernel`` along ``dim``.

    psp(x)[t] = Σ_k kernel[k]·x[t − k] (Ts = 1 ms), zero history before t = 0. Differentiable in
    ``x`` and, when it requires a gradient (a learned time constant), in ``kernel``.

    Args:
        x: spikes (or any signal), time along ``dim`` in 1 ms steps.
        kernel: 1-D tensor, kernel[k] = response k steps after an input, e.g.
            :func:`spikegyro.snn.kernels.srm_kernel`.
        dim: the time axis.

    Returns:
        Tensor shaped like ``x``; its storage is time-major (a permuted view when ``dim`` is not 0).
    """
    if kernel.dim() != 1 or kernel.numel() == 0:
        raise ValueError(f"kernel must be a non-empty 1-D tensor, got shape {tuple(kernel.shape)}")
    view = _TimeRows(x, dim)
    return view.back(_PSPFunction.apply(view.rows, kernel))


def surrogate_half_width(theta: float, tau_rho: float = TAU_RHO, cut: float = 0.0) -> float:
    """Half-width of the bounded surrogate's support (potential units): ρ(u) is kept where
    |u − θ| ≤ tau_rho·θ·ln(1/cut), i.e. where the pdf is at least ``cut`` times its peak, and is 0
    elsewhere. ``cut = 0`` is SLAYER's unbounded pdf (infinite width).

    At tau_rho = 0.3 the cut 0.2 (the event-driven engine's default) keeps |u − θ| ≤ 0.48θ, and
    0.05 keeps |u − θ| ≤ 0.9θ: on the windows of ``bench/train_step.py`` 4-9 % and 10-18 % of
    SNN-6's (neuron, step) pairs per layer, which is what the event-driven backward pass
    (:mod:`spikegyro.snn.sparse`) visits.
    """
    if not 0.0 <= cut < 1.0:
        raise ValueError(f"surrogate cut must be in [0, 1), got {cut}")
    return math.inf if cut == 0.0 else tau_rho * theta * math.log(1.0 / cut)


def surrogate_gradient(
    potential: torch.Tensor,
    theta: float,
    scale_rho: float,
    tau_rho: float = TAU_RHO,
    cut: float = 0.0,
) -> torch.Tensor:
    """Spike pdf ρ(u) = (scale_rho/θ)·exp(−|u − θ|/(tau_rho·θ)), used as ∂spike/∂u (per unit u).

    ``cut`` > 0 bounds its support: ρ = 0 where the pdf falls below ``cut`` times its peak
    (see :func:`surrogate_half_width`).
    """
    distance = (potential - theta).abs_()
    outside = distance > surrogate_half_width(theta, tau_rho, cut) if cut > 0 else None
    rho = distance.mul_(-1.0 / (tau_rho * theta)).exp_().mul_(scale_rho / theta)
    return rho if outside is None else rho.masked_fill_(outside, 0.0)


def _fire_rows(
    rows: torch.Tensor, theta: float, ref_kernel: torch.Tensor, *, in_place: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Spike recursion on a (T, M) potential; returns (spikes, potential with refractoriness).

    At step t every neuron with u[t] ≥ θ spikes, and ν[k]·spike is added to its u[t + k] for
    k = 1 … len(ν) − 1 (ν[0] must be 0). Whole-row operations only; the loop is over time.
    ``in_place`` adds the refractory responses to ``rows`` itself (which must be contiguous).
    On CUDA (float32, Triton installed) one fused kernel does the whole recursion, with
    bit-identical results (:mod:`spikegyro.snn.triton_kernels`).
    """
    _check_ref_kernel(ref_kernel)
    fused = _fused(rows, ref_kernel)
    if fused is not None:
        return fused.fire_rows(rows, theta, ref_kernel, in_place=in_place)
    if in_place:
        potential = rows
    else:
        potential = torch.empty(rows.shape, dtype=rows.dtype, device=rows.device)
        potential.copy_(rows)
    spikes = torch.empty_like(potential)
    taps = ref_kernel[1:].to(device=rows.device, dtype=rows.dtype)[:, None]
    steps = rows.shape[0]
    with _one_cpu_thread(rows):
        for t in range(steps):
            torch.ge(potential[t], theta, out=spikes[t])
            ahead = min(taps.shape[0], steps - 1 - t)
            if ahead:
                potential[t + 1 : t + 1 + ahead].addcmul_(taps[:ahead], spikes[t])
    return spikes, potential


def _check_ref_kernel(ref_kernel: torch.Tensor) -> None:
    if ref_kernel.dim() != 1 or ref_kernel.numel() == 0:
        raise ValueError("ref_kernel must be a non-empty 1-D tensor")
    # Reading tap 0 of a CUDA kernel waits for the device, which a CUDA graph capture forbids;
    # tap 0 is never used (the loops start at k = 1), so the check only guards the contract.
    capturing = ref_kernel.is_cuda and torch.cuda.is_current_stream_capturing()
    if not capturing and float(ref_kernel[0]) != 0.0:
        raise ValueError("ref_kernel must be a 1-D tensor with ref_kernel[0] == 0")


@contextlib.contextmanager
def _one_cpu_thread(rows: torch.Tensor) -> Iterator[None]:
    """Run the per-step loop over ``rows`` on one CPU thread.

    Each step is a few small element-wise operations; splitting them over threads gains little,
    and on a shared machine every op waits for its slowest (descheduled) worker: a training step
    of SNN-6 measured 25-35 % faster this way with 2 threads on 2 busy cores. Rows shorter than
    PyTorch's parallel grain size run on one thread anyway, and switching costs time, so those
    are left alone.
    """
    threads = torch.get_num_threads()
    if rows.device.type != "cpu" or threads == 1 or rows.shape[-1] < _PARALLEL_GRAIN:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class _SpikeFunction(torch.autograd.Function):
    """Threshold + refractory recursion forward; surrogate ρ(u) backward, none through ν.

    When ν requires a gradient (a learned τr), ∂L/∂ν[k] = Σ_t δ[t]·s[t − k] with δ = ρ(u)·∂L/∂s:
    the derivative of u wrt ν holding the spikes that ν acts on fixed, the one part of the
    refractory term that SLAYER's rule (no gradient through the feedback) leaves.
    """

    @staticmethod
    def forward(
        ctx,
        rows: torch.Tensor,
        theta: float,
        ref_kernel: torch.Tensor,
        scale_rho: float,
        tau_rho: float,
        overwrite: bool,
        cut: float = 0.0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        in_place = overwrite and rows.is_contiguous()
        spikes, potential = _fire_rows(rows, theta, ref_kernel, in_place=in_place)
        if in_place:
            ctx.mark_dirty(rows)
        ctx.mark_non_differentiable(potential)
        ctx.set_materialize_grads(False)  # no zero-filled gradient for the potential output
        fired = spikes.to(torch.bool) if ref_kernel.requires_grad else None
        ctx.save_for_backward(potential, ref_kernel, fired)
        ctx.constants = (theta, scale_rho, tau_rho, cut)
        return spikes, potential

    @staticmethod
    def backward(
        ctx, grad: torch.Tensor | None, _: torch.Tensor | None
    ) -> tuple[torch.Tensor | None, ...]:
        if grad is None:
            return (None,) * 7
        potential, ref_kernel, fired = ctx.saved_tensors
        theta, scale_rho, tau_rho, cut = ctx.constants
        fused = _fused(potential) if cut == 0.0 else None  # the fused kernel has no cut
        if fused is not None:
            rho = fused.surrogate_backward(potential, grad, theta, scale_rho, tau_rho)
        else:
            rho = surrogate_gradient(potential, theta, scale_rho, tau_rho, cut).mul_(grad)
        grad_ref = None
        if ctx.needs_input_grad[2]:
            spikes = fired.to(rho.dtype)
            grad_ref = kernel_gradient(rho, spikes, ref_kernel.numel()).to(ref_kernel.dtype)
        return rho, None, grad_ref, None, None, None, None


def spike_fn(
    potential: torch.Tensor,
    theta: float,
    ref_kernel: torch.Tensor,
    scale_rho: float,
    tau_rho: float = TAU_RHO,
    dim: int = -1,
    *,
    overwrite: bool = False,
    cut: float = 0.0,
) -> torch.Tensor:
    """Spikes of SRM neurons driven by the sub-threshold ``potential``, with SLAYER's gradient.

    Forward: a neuron spikes (output 1) at step t when its potential u[t] ≥ θ, and the refractory
    kernel ν is added to its own potential at the following steps. Backward: ∂L/∂potential =
    ∂L/∂spikes · ρ(u), ρ from :func:`surrogate_gradient` at the potential including refractory
    responses; no gradient flows through the refractory feedback.

    Args:
        potential: membrane potential before refractory responses, time along ``dim`` (1 ms).
        theta: threshold θ; ref_kernel: ν from :func:`spikegyro.snn.kernels.refractory_kernel`
            (differentiable as described in :class:`_SpikeFunction` when it requires a gradient).
        scale_rho, tau_rho: surrogate height (relative to 1/θ) and width (relative to θ).
        dim: the time axis.
        overwrite: reuse the storage of ``potential`` (when time-major) for the potential with
            refractory responses that the backward pass keeps; saves a copy, destroys the input.
        cut: bound the surrogate's support where the pdf falls below this share of its peak
            (0 = unbounded, SLAYER's; see :func:`surrogate_half_width`).

    Returns:
        0/1 spikes shaped like ``potential`` (time-major storage).
    """
    view = _TimeRows(potential, dim)
    spikes, _ = _SpikeFunction.apply(
        view.rows, theta, ref_kernel, scale_rho, tau_rho, overwrite, cut
    )
    return view.back(spikes)


@torch.no_grad()
def fire(
    potential: torch.Tensor, theta: float, ref_kernel: torch.Tensor, dim: int = -1
) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward of :func:`spike_fn` without gradients; returns (spikes, potential with ν added)."""
    view = _TimeRows(potential, dim)
    spikes, full = _fire_rows(view.rows, theta, ref_kernel)
    return view.back(spikes), view.back(full)


class _BinaryInputConv(torch.autograd.Function):
    """conv2d whose 0/1 input is kept for the weight gradient as booleans (4x less memory)."""

    @staticmethod
    def forward(
        ctx, images: torch.Tensor, weight: torch.Tensor, stride: int, padding: int
    ) -> torch.Tensor:
        ctx.save_for_backward(images.to(torch.bool), weight)
        ctx.geometry = (stride, padding, images.dtype)
        return F.conv2d(images, weight, stride=stride, padding=padding)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        packed, weight = ctx.saved_tensors
        stride, padding, dtype = ctx.geometry
        grad_images, grad_weight, _ = torch.ops.aten.convolution_backward(
            grad,
            packed.to(dtype),
            weight,
            None,
            [stride, stride],
            [padding, padding],
            [1, 1],
            False,
            [0, 0],
            1,
            [ctx.needs_input_grad[0], ctx.needs_input_grad[1], False],
        )
        return grad_images, grad_weight, None, None


def conv_over_time(
    x: torch.Tensor,
    weight: torch.Tensor,
    stride: int = 1,
    padding: int = 0,
    *,
    binary: bool = False,
) -> torch.Tensor:
    """2-D convolution applied at every time step at once (time folded into the batch).

    Args:
        x: (T, N, C_in, H, W), time-major.
        weight: (C_out, C_in, kH, kW).
        binary: ``x`` holds only 0 and 1 (spikes); it is then kept for the backward pass as
            booleans (4x less memory). Not checked: graded input with ``binary=True`` gives
            wrong weight gradients.

    Returns:
        (T, N, C_out, H_out, W_out), stored time-major and channels-last, i.e. as a contiguous
        (T, N, H_out, W_out, C_out) block (the convolution is >2x faster channels-last on CPU for
        these few channels).
    """
    steps, batch, channels, height, width = x.shape
    # A no-op when x already comes from this function (through the spike layers).
    nhwc = x.permute(0, 1, 3, 4, 2).contiguous()
    images = nhwc.reshape(steps * batch, height, width, channels).permute(0, 3, 1, 2)
    if binary:
        y = _BinaryInputConv.apply(images, weight, stride, padding)
    else:
        y = F.conv2d(images, weight, stride=stride, padding=padding)
    y = y.contiguous(memory_format=torch.channels_last)
    return y.reshape(steps, batch, *y.shape[1:])
