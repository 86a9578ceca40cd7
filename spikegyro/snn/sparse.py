"""Event-driven training of a stack of SRM conv layers with a pooled, filtered readout (CPU).

:func:`sparse_loss_backward` computes the loss of a batch and the gradients of every weight that
requires one, as ``loss.backward()`` through the batch path would with the same bounded
surrogate (``SRMParams.rho_cut`` > 0), but visits only the input spikes (forward,
:mod:`spikegyro.snn.sparse_forward`) and the (neuron, step) pairs within the surrogate's support
(backward, :mod:`spikegyro.snn.sparse_backward`). The pooling, the dense readout and the loss
are small and run through torch's autograd on the pooled layer-5 spike counts, so the readout
is the model's own module, exactly.

Each batch element runs on one thread (Numba releases the GIL); ``threads`` elements run at once.
Work and memory grow with the number of spikes and active pairs, not with the number of neurons
times steps. Float32 weights run in float32 (the comparisons with θ as the batch path makes
them), float64 weights in float64.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numba
import numpy as np
import torch
from torch import nn

from spikegyro.snn.functional import surrogate_half_width
from spikegyro.snn.layers import SRMConv, SRMDense
from spikegyro.snn.sparse_backward import layer_backward
from spikegyro.snn.sparse_forward import (
    alpha_constants,
    dense_to_lists,
    fanout_tables,
    layer_forward,
)

Lists = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(offsets (T + 1,), flat indices, values): one step-major event list."""


@dataclass(frozen=True)
class _Layer:
    """One conv layer as the Numba kernels take it (arrays in the engine's dtype)."""

    weight: np.ndarray  # (kh, kw, C_in, C_out), C-contiguous
    stride: int
    in_width: int
    out_shape: tuple[int, int]
    rows: tuple[np.ndarray, np.ndarray]
    cols: tuple[np.ndarray, np.ndarray]
    alpha: np.ndarray
    taps: int
    eps: np.ndarray
    ref: np.ndarray
    theta: np.generic
    half_width: np.generic
    surrogate: np.ndarray

    @classmethod
    def of(cls, conv: SRMConv, in_hw: tuple[int, int], dtype: type) -> _Layer:
        p = conv.params
        if not p.spiking or conv.padding:
            raise ValueError("the event-driven engine runs spiking conv layers without padding")
        width = surrogate_half_width(p.theta, p.tau_rho, p.rho_cut)
        if not width < p.theta:
            limit = float(np.exp(-1.0 / p.tau_rho))
            raise ValueError(
                f"the event-driven engine needs a bounded surrogate with support inside (0, 2θ): "
                f"rho_cut > {limit:.4f} (got {p.rho_cut})"
            )
        kernel = conv.weight.shape[-1]
        out_hw = conv.output_size(*in_hw)
        alpha, taps = alpha_constants(conv.srm_kernel.detach().double().cpu().numpy(), dtype)
        weight = conv.weight.detach().permute(2, 3, 1, 0).cpu().numpy().astype(dtype)
        return cls(
            weight=np.ascontiguousarray(weight),
            stride=conv.stride,
            in_width=in_hw[1],
            out_shape=out_hw,
            rows=fanout_tables(in_hw[0], out_hw[0], kernel, conv.stride),
            cols=fanout_tables(in_hw[1], out_hw[1], kernel, conv.stride),
            alpha=alpha,
            taps=taps,
            eps=conv.srm_kernel.detach().cpu().numpy().astype(dtype),
            ref=conv.ref_kernel.detach().cpu().numpy().astype(dtype),
            theta=dtype(p.theta),
            half_width=dtype(width),
            surrogate=np.array(
                [p.theta, p.scale_rho / p.theta, -1.0 / (p.tau_rho * p.theta)], dtype=dtype
            ),
        )

    def forward(self, inputs: Lists, record: bool) -> tuple[Lists, tuple[np.ndarray, ...]]:
        """(output spike lists, (active offsets, indices, potentials))."""
        spk_off, spk_idx, act_off, act_idx, act_u = layer_forward(
            *inputs, self.in_width, self.weight, self.stride, self.out_shape, self.rows,
            self.cols, self.alpha, self.taps, self.ref, self.theta, self.half_width, record,
        )  # fmt: skip
        return (spk_off, spk_idx, np.ones(spk_idx.size, self.weight.dtype)), (
            act_off,
            act_idx,
            act_u,
        )


@dataclass
class _Element:
    """What the forward pass of one batch element keeps for its backward pass."""

    inputs: list[Lists] = field(default_factory=list)  # the input of each layer
    active: list[tuple[np.ndarray, ...]] = field(default_factory=list)
    pooled: np.ndarray | None = None  # (features, T)


@numba.njit(cache=True, nogil=True)
def _pool_forward(
    offsets: np.ndarray, index: np.ndarray, pooling: np.ndarray, channels: int
) -> np.ndarray:
    """(channels·cells, T) pooled spikes: feature c·cells + cell = Σ_pixel pooling[cell, pixel]·s."""
    steps = offsets.size - 1
    cells = pooling.shape[0]
    out = np.zeros((channels * cells, steps), pooling.dtype)
    for t in range(steps):
        for i in range(offsets[t], offsets[t + 1]):
            pixel, c = divmod(index[i], channels)
            for cell in range(cells):
                out[c * cells + cell, t] += pooling[cell, pixel]
    return out


@numba.njit(cache=True, nogil=True)
def _pool_backward(
    offsets: np.ndarray, index: np.ndarray, grad: np.ndarray, pooling: np.ndarray, channels: int
) -> np.ndarray:
    """∂L/∂s at the pairs (offsets, index) from ∂L/∂pooled (features, T)."""
    cells = pooling.shape[0]
    out = np.zeros(index.size, grad.dtype)
    for t in range(offsets.size - 1):
        for i in range(offsets[t], offsets[t + 1]):
            pixel, c = divmod(index[i], channels)
            total = grad[0, 0] * 0
            for cell in range(cells):
                total += pooling[cell, pixel] * grad[c * cells + cell, t]
            out[i] = total
    return out


def pooling_matrix(pool: nn.Module, height: int, width: int, dtype: torch.dtype) -> np.ndarray:
    """(cells, height·width) weights of a linear spatial pooling module (GASP, RegionPool),
    read off its response to one-hot maps."""
    pixels = height * width
    basis = torch.eye(pixels, dtype=dtype).reshape(1, 1, height, width, pixels)
    with torch.no_grad():
        return pool(basis)[0].cpu().numpy()


@dataclass
class SparseTiming:
    """Seconds spent in each part of the last :func:`sparse_loss_backward` call (wall time of
    the parallel sections)."""

    forward_s: float = 0.0
    readout_s: float = 0.0
    backward_s: float = 0.0
    inputs: int = 0
    spikes: list[int] = field(default_factory=list)
    active: list[int] = field(default_factory=list)


LAST_TIMING = SparseTiming()
"""Filled by every call (for profiling; not thread-safe across concurrent calls)."""


def sparse_loss_backward(
    convs: Sequence[SRMConv],
    pool: nn.Module,
    readout: SRMDense,
    x: torch.Tensor,
    loss_fn: Callable[[torch.Tensor], torch.Tensor],
    *,
    threads: int = 1,
) -> torch.Tensor:
    """Loss of a batch, with ∂loss/∂weight accumulated into ``.grad`` of every weight that
    requires a gradient, as the batch path's ``loss.backward()`` with the same bounded surrogate.

    Args:
        convs: spiking conv layers (no padding), each with ``params.rho_cut`` above
            exp(−1/tau_rho) (so that the support excludes rest, u = 0).
        pool: linear spatial pooling of the last layer's spikes (GASP or RegionPool).
        readout: the non-spiking dense readout (PSP of the weighted pooled spikes).
        x: input (N, C, H, W, T), time last, 1 ms steps (0/1 spikes or event counts).
        loss_fn: maps the readout's output (N, outputs, T) to a scalar loss.
        threads: batch elements processed at once, one per thread.

    Returns:
        The (detached) loss.
    """
    dtype = np.float64 if readout.weight.dtype == torch.float64 else np.float32
    layers, size = [], tuple(x.shape[2:4])
    for conv in convs:
        layers.append(_Layer.of(conv, size, dtype))
        size = layers[-1].out_shape
    trainable = [conv.weight.requires_grad for conv in convs]
    first = trainable.index(True) if any(trainable) else len(convs)
    pooling = pooling_matrix(pool, *size, readout.weight.dtype).astype(dtype)
    channels = layers[-1].weight.shape[3]
    timing = SparseTiming()
    with ThreadPoolExecutor(max(1, threads)) as workers:
        start = time.perf_counter()
        x_np = x.detach().cpu().numpy()
        elements = list(
            workers.map(
                lambda b: _forward_element(x_np[b], layers, first, pooling, channels, dtype),
                range(x.shape[0]),
            )
        )
        timing.forward_s = time.perf_counter() - start
        start = time.perf_counter()
        pooled = torch.from_numpy(np.stack([e.pooled for e in elements])).to(readout.weight)
        pooled.requires_grad_(first < len(convs))
        loss = loss_fn(readout(pooled))
        loss.backward()
        timing.readout_s = time.perf_counter() - start
        start = time.perf_counter()
        if pooled.grad is not None:
            grad_pooled = pooled.grad.cpu().numpy().astype(dtype)
            grads = list(
                workers.map(
                    lambda b: _backward_element(
                        elements[b], grad_pooled[b], layers, first, pooling, channels
                    ),
                    range(x.shape[0]),
                )
            )
            _accumulate(convs, first, grads)
        timing.backward_s = time.perf_counter() - start
    timing.inputs = sum(int(e.inputs[0][1].size) for e in elements)
    timing.spikes = [sum(int(e.inputs[i][1].size) for e in elements) for i in range(1, len(convs))]
    timing.active = [sum(int(e.active[i][1].size) for e in elements) for i in range(len(convs))]
    LAST_TIMING.__dict__.update(timing.__dict__)
    return loss.detach()


def _forward_element(
    x: np.ndarray,
    layers: list[_Layer],
    first: int,
    pooling: np.ndarray,
    channels: int,
    dtype: type,
) -> _Element:
    """Forward pass of one (C, H, W, T) input; keeps each layer's input lists and active pairs."""
    offsets, index, values = dense_to_lists(np.ascontiguousarray(x))
    spikes: Lists = (offsets, index, values.astype(dtype))
    element = _Element()
    for i, layer in enumerate(layers):
        element.inputs.append(spikes)
        spikes, active = layer.forward(spikes, record=i >= first)
        element.active.append(active)
    element.pooled = _pool_forward(spikes[0], spikes[1], pooling, channels)
    return element


def _backward_element(
    element: _Element,
    grad_pooled: np.ndarray,
    layers: list[_Layer],
    first: int,
    pooling: np.ndarray,
    channels: int,
) -> list[np.ndarray]:
    """Weight gradients (kh, kw, C_in, C_out) of layers ``first`` … last for one element."""
    act_off, act_idx, _ = element.active[-1]
    grad_s = _pool_backward(act_off, act_idx, grad_pooled, pooling, channels)
    grads = []
    for i in range(len(layers) - 1, first - 1, -1):
        layer = layers[i]
        act_off, act_idx, act_u = element.active[i]
        below = element.active[i - 1][:2] if i > first else (act_off[:1], act_idx[:0])
        grad_w, grad_s = layer_backward(
            act_off, act_idx, act_u, grad_s, layer.surrogate, layer.eps, layer.out_shape,
            element.inputs[i], layer.in_width, layer.weight, layer.stride, layer.rows,
            layer.cols, below, i > first,
        )  # fmt: skip
        grads.append(grad_w)
    return grads[::-1]


def _accumulate(convs: Sequence[SRMConv], first: int, grads: list[list[np.ndarray]]) -> None:
    """Sum the elements' weight gradients into ``.grad`` (autograd's accumulation rule)."""
    for i, conv in enumerate(convs[first:]):
        total = grads[0][i].copy()
        for element in grads[1:]:
            total += element[i]
        if not conv.weight.requires_grad:
            continue
        grad = torch.from_numpy(total).permute(3, 2, 0, 1).to(conv.weight)
        if conv.weight.grad is None:
            conv.weight.grad = grad.contiguous()
        else:
            conv.weight.grad += grad
