"""Event-driven training of a stack of SRM conv layers with a pooled, filtered readout (CPU).

:class:`EventDrivenStack` runs the spiking layers of a network on the CPU and plugs into torch's
autograd: ``loss.backward()`` gives every conv weight the gradient that the batch path gives with
the same bounded surrogate (``SRMParams.rho_cut`` > 0), but the forward pass visits only the
input spikes (:mod:`spikegyro.snn.sparse_forward`) and the backward pass only the (neuron, step)
pairs within the surrogate's support (:mod:`spikegyro.snn.sparse_backward`). Its output is the
pooled last-layer spikes; the dense readout and the loss downstream are the model's own torch
code.

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
from typing import Any

import numba
import numpy as np
import torch
from torch import nn

from spikegyro.snn.functional import surrogate_half_width
from spikegyro.snn.layers import SRMConv
from spikegyro.snn.sparse_backward import layer_backward
from spikegyro.snn.sparse_forward import (
    alpha_constants,
    dense_to_lists,
    fanout,
    layer_forward,
    refractory_constants,
)

Lists = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(offsets (T + 1,), flat indices, values): one step-major event list."""


@dataclass(frozen=True)
class _Layer:
    """One conv layer as the Numba kernels take it (arrays in the engine's dtype)."""

    weight: np.ndarray  # (kh·kw, C_in, C_out), C-contiguous
    geometry: np.ndarray  # [stride, input width, output width, kernel width], px
    out_shape: tuple[int, int]
    fan: tuple[np.ndarray, np.ndarray]  # what each input pixel reaches (fanout)
    alpha: np.ndarray
    taps: int
    refractory: tuple[np.ndarray, int]
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
        weight = conv.weight.detach().permute(2, 3, 1, 0).flatten(0, 1).cpu().numpy()
        return cls(
            weight=np.ascontiguousarray(weight.astype(dtype)),
            geometry=np.array([conv.stride, in_hw[1], out_hw[1], kernel], np.int64),
            out_shape=out_hw,
            fan=fanout(in_hw, out_hw, kernel, conv.stride),
            alpha=alpha,
            taps=taps,
            refractory=refractory_constants(conv.ref_kernel.detach().double().cpu().numpy(), dtype),
            theta=dtype(p.theta),
            half_width=dtype(width),
            surrogate=np.array(
                [p.theta, p.scale_rho / p.theta, -1.0 / (p.tau_rho * p.theta)], dtype=dtype
            ),
        )

    @property
    def out_pixels(self) -> int:
        return self.out_shape[0] * self.out_shape[1]

    def forward(self, inputs: Lists, record: bool) -> tuple[Lists, tuple[np.ndarray, ...]]:
        """(output spike lists, (active offsets, indices, potentials))."""
        spk_off, spk_idx, act_off, act_idx, act_u = layer_forward(
            inputs, self.weight, self.geometry, self.out_pixels, self.fan,
            self.alpha, self.taps, self.refractory, (self.theta, self.half_width, record),
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
    forward_s: list[float] = field(default_factory=list)  # per layer
    backward_s: list[float] = field(default_factory=list)  # per layer, last layer first


@numba.njit(cache=True, nogil=True)
def _pool_forward(
    offsets: np.ndarray, index: np.ndarray, pooling: np.ndarray, channels: int
) -> np.ndarray:
    """(channels·cells, T) pooled spikes: feature c·cells + cell sums pooling[cell, px]·s[px, c]."""
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
    zero = np.zeros(1, grad.dtype)[0]  # a literal 0 would make the sum float64
    for t in range(offsets.size - 1):
        for i in range(offsets[t], offsets[t + 1]):
            pixel, c = divmod(index[i], channels)
            total = zero
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
    """Seconds spent in the parts of the last step of an :class:`EventDrivenStack` and what they
    processed (summed over the batch): wall time of the parallel sections, and per layer the CPU
    time of the threads that ran it (a thread waiting for a busy core is not counted)."""

    forward_s: float = 0.0
    backward_s: float = 0.0
    layer_forward_s: list[float] = field(default_factory=list)  # thread CPU s per layer, summed
    layer_backward_s: list[float] = field(default_factory=list)
    inputs: int = 0
    spikes: list[int] = field(default_factory=list)
    active: list[int] = field(default_factory=list)


class EventDrivenStack:
    """The event-driven engine for a stack of spiking conv layers and a linear spatial pooling.

    ``pooled(x)`` returns the pooled spikes of the last layer, (N, features, T), exactly as the
    batch path computes them; when grad mode is on and some conv weight requires a gradient, the
    result is attached to the autograd graph so that ``backward()`` through it accumulates each
    conv weight's gradient (the event-driven backward pass). The readout and the loss downstream
    stay ordinary torch code.

    Args:
        convs: spiking conv layers (no padding), each with ``params.rho_cut`` above
            exp(−1/tau_rho) (so that the support excludes rest, u = 0).
        pool: linear spatial pooling of the last layer's spikes (GASP or RegionPool).
        threads: batch elements processed at once, one per thread.
    """

    def __init__(self, convs: Sequence[SRMConv], pool: nn.Module, threads: int = 1) -> None:
        self.convs = tuple(convs)
        self.pool = pool
        self.threads = max(1, int(threads))
        self.timing = SparseTiming()

    def pooled(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled last-layer spikes (N, features, T) of input (N, C, H, W, T) (time last, 1 ms)."""
        weights = [conv.weight for conv in self.convs]
        if torch.is_grad_enabled() and any(w.requires_grad for w in weights):
            return _EventDrivenFunction.apply(self, x, *weights)
        return self._forward(x, record=False)[0]

    def _forward(self, x: torch.Tensor, record: bool) -> tuple[torch.Tensor, _Plan]:
        weight = self.convs[0].weight
        dtype = np.float64 if weight.dtype == torch.float64 else np.float32
        plan = _Plan.of(self.convs, self.pool, tuple(x.shape[2:4]), dtype, record)
        start = time.perf_counter()
        x_np = x.detach().cpu().numpy()
        # The input's sum (its event count) orders the elements by cost: a torch sum on all
        # threads costs a fifth of counting the non-zeros, and the order only balances the load.
        costs = x.detach().flatten(1).sum(1).tolist()
        plan.elements = self._map(lambda b: plan.forward_element(x_np[b]), costs)
        self.timing = SparseTiming(forward_s=time.perf_counter() - start)
        self.timing.layer_forward_s = np.sum([e.forward_s for e in plan.elements], axis=0).tolist()
        self.timing.inputs = sum(int(e.inputs[0][1].size) for e in plan.elements)
        self.timing.spikes = [
            sum(int(e.inputs[i][1].size) for e in plan.elements) for i in range(1, len(self.convs))
        ]
        self.timing.active = [
            sum(int(e.active[i][1].size) for e in plan.elements) for i in range(len(self.convs))
        ]
        pooled = np.stack([e.pooled for e in plan.elements])
        return torch.from_numpy(pooled).to(device=x.device, dtype=weight.dtype), plan

    def _backward(self, plan: _Plan, grad_pooled: torch.Tensor) -> list[torch.Tensor | None]:
        start = time.perf_counter()
        grad_np = grad_pooled.detach().cpu().numpy().astype(plan.dtype)
        costs = [sum(a[1].size for a in e.active) for e in plan.elements]
        per_element = self._map(
            lambda b: plan.backward_element(plan.elements[b], grad_np[b]), costs
        )
        self.timing.backward_s = time.perf_counter() - start
        per_layer = np.sum([e.backward_s[::-1] for e in plan.elements], axis=0)
        self.timing.layer_backward_s = [0.0] * plan.first + per_layer.tolist()
        grads: list[torch.Tensor | None] = [None] * plan.first
        for i, conv in enumerate(self.convs[plan.first :]):
            total = per_element[0][i].copy()
            for element in per_element[1:]:
                total += element[i]
            shaped = total.reshape(*conv.weight.shape[2:], *total.shape[1:])  # (kh, kw, in, out)
            grads.append(torch.from_numpy(shaped).permute(3, 2, 0, 1).contiguous().to(conv.weight))
        return grads

    def _map(self, fn: Callable[[int], Any], costs: Sequence[int]) -> list[Any]:
        """[fn(0), fn(1), …] for the batch elements, on ``threads`` threads, the costliest
        (by ``costs``) started first so that no thread is left with a long one at the end."""
        count = len(costs)
        if self.threads == 1 or count == 1:
            return [fn(b) for b in range(count)]
        order = sorted(range(count), key=lambda b: -costs[b])
        with ThreadPoolExecutor(min(self.threads, count)) as workers:
            done = dict(zip(order, workers.map(fn, order), strict=True))
        return [done[b] for b in range(count)]


class _EventDrivenFunction(torch.autograd.Function):
    """Autograd node of :meth:`EventDrivenStack.pooled`: the conv weights' gradients come from
    the event-driven backward pass."""

    @staticmethod
    def forward(ctx, engine: EventDrivenStack, x: torch.Tensor, *weights: torch.Tensor):
        pooled, plan = engine._forward(x, record=True)
        ctx.engine, ctx.plan = engine, plan
        return pooled

    @staticmethod
    def backward(ctx, grad_pooled: torch.Tensor):
        grads = ctx.engine._backward(ctx.plan, grad_pooled)
        ctx.plan = None  # free the spike and active lists
        return (None, None, *grads)


@dataclass
class _Plan:
    """The layers of one step, as the kernels take them, and what each element's forward kept."""

    layers: list[_Layer]
    first: int  # the first layer whose weight learns (len(layers): none)
    pooling: np.ndarray
    dtype: type
    elements: list[_Element] = field(default_factory=list)

    @classmethod
    def of(
        cls,
        convs: Sequence[SRMConv],
        pool: nn.Module,
        size: tuple[int, int],
        dtype: type,
        record: bool,
    ) -> _Plan:
        layers = []
        for conv in convs:
            layers.append(_Layer.of(conv, size, dtype))
            size = layers[-1].out_shape
        trainable = [record and conv.weight.requires_grad for conv in convs]
        first = trainable.index(True) if any(trainable) else len(convs)
        pooling = pooling_matrix(pool, *size, convs[0].weight.dtype).astype(dtype)
        return cls(layers, first, pooling, dtype)

    @property
    def channels(self) -> int:
        return self.layers[-1].weight.shape[2]

    def forward_element(self, x: np.ndarray) -> _Element:
        """Forward pass of one (C, H, W, T) input; keeps each layer's input and active pairs."""
        offsets, index, values = dense_to_lists(np.ascontiguousarray(x))
        spikes: Lists = (offsets, index, values.astype(self.dtype))
        element = _Element()
        for i, layer in enumerate(self.layers):
            element.inputs.append(spikes)
            start = time.thread_time()
            spikes, active = layer.forward(spikes, record=i >= self.first)
            element.forward_s.append(time.thread_time() - start)
            element.active.append(active)
        element.pooled = _pool_forward(spikes[0], spikes[1], self.pooling, self.channels)
        return element

    def backward_element(self, element: _Element, grad_pooled: np.ndarray) -> list[np.ndarray]:
        """Weight gradients (kh·kw, C_in, C_out) of layers ``first`` … last for one element."""
        act_off, act_idx, _ = element.active[-1]
        grad_s = _pool_backward(act_off, act_idx, grad_pooled, self.pooling, self.channels)
        grads = []
        for i in range(len(self.layers) - 1, self.first - 1, -1):
            layer = self.layers[i]
            start = time.thread_time()
            act_off, act_idx, _ = element.active[i]
            below = element.active[i - 1][:2] if i > self.first else (act_off, act_idx[:0])
            grad_w, grad_s = layer_backward(
                element.active[i], grad_s, layer.surrogate, layer.alpha, layer.taps,
                element.inputs[i], layer.weight, layer.fan, layer.out_pixels, below,
            )  # fmt: skip
            grads.append(grad_w)
            element.backward_s.append(time.thread_time() - start)
        return grads[::-1]
