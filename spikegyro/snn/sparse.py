"""Event-driven training of a stack of SRM conv layers with a pooled, filtered readout (CPU).

:class:`EventDrivenStack` runs the spiking layers of a network on the CPU and plugs into torch's
autograd: ``loss.backward()`` gives every conv weight the gradient that the batch path gives with
the same bounded surrogate (``SRMParams.rho_cut`` > 0), but the forward pass visits only the
input spikes (:mod:`spikegyro.snn.sparse_forward`) and the backward pass only the (neuron, step)
pairs within the surrogate's support (:mod:`spikegyro.snn.sparse_backward`). Its output is the
pooled last-layer spikes; the dense readout and the loss downstream are the model's own torch
code. Its input is a dense spike tensor or a sparse COO one
(:func:`spikegyro.events.binning_torch.spike_tensor` with ``sparse``, as training gives it), whose
entries it reads without a dense copy.

The layers of the batch elements run as tasks on ``threads`` threads (Numba releases the GIL),
each element's layers in order.
Work and memory grow with the number of spikes and active pairs, not with the number of neurons
times steps. Float32 weights run in float32 (the comparisons with θ as the batch path makes
them), float64 weights in float64.
"""

from __future__ import annotations

import heapq
import threading
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
from spikegyro.snn.sparse_backward import layer_backward, surrogate_pdf, tau_gradient
from spikegyro.snn.sparse_forward import (
    Buffers,
    alpha_constants,
    channel_blocks,
    coo_to_lists,
    dense_to_lists,
    divisor,
    fanout,
    layer_forward,
    quotient,
    refractory_constants,
    unblocked,
)

Lists = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(offsets (T + 1,), flat indices, values): one step-major event list."""

Kept = dict[str, tuple[np.ndarray, ...]]
"""Named buffers that a kernel writes into, kept between calls (see :class:`_Storage`)."""


@dataclass(frozen=True)
class _Layer:
    """One conv layer as the Numba kernels take it (arrays in the engine's dtype)."""

    weight: np.ndarray  # (blocks, kh·kw, C_in, C_out / blocks): channel_blocks
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
    def of(cls, conv: SRMConv, in_hw: tuple[int, int], dtype: type, tau: bool = False) -> _Layer:
        """The layer ``conv`` for ``in_hw`` (px) input in ``dtype``; ``tau``: its passes also
        compute ∂u/∂τs and ∂u/∂τr (learned time constants)."""
        p = conv.current_params()
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
        with torch.no_grad():
            srm, ref = (k.double().cpu().numpy() for k in conv.current_kernels())
        alpha, taps = alpha_constants(srm, dtype, p.tau_s if tau else None)
        weight = conv.weight.detach().permute(2, 3, 1, 0).flatten(0, 1).cpu().numpy()
        return cls(
            weight=channel_blocks(weight.astype(dtype)),
            geometry=np.array([conv.stride, in_hw[1], out_hw[1], kernel], np.int64),
            out_shape=out_hw,
            fan=fanout(in_hw, out_hw, kernel, conv.stride),
            alpha=alpha,
            taps=taps,
            refractory=refractory_constants(ref, dtype, p.tau_r if tau else None),
            theta=dtype(p.theta),
            half_width=dtype(width),
            surrogate=np.array(
                [p.theta, p.scale_rho / p.theta, -1.0 / (p.tau_rho * p.theta)], dtype=dtype
            ),
        )

    @property
    def out_channels(self) -> int:
        return self.weight.shape[0] * self.weight.shape[3]

    @property
    def out_pixels(self) -> int:
        return self.out_shape[0] * self.out_shape[1]

    def forward(
        self, inputs: Lists, record: bool, storage: _Storage, key: str
    ) -> tuple[Lists, tuple[np.ndarray, ...], np.ndarray]:
        """(output spike lists, (active offsets (tiles, T + 1), indices, potentials), ∂u/∂τs
        and ∂u/∂τr of the active pairs interleaved (empty unless the layer computes them)),
        written into the buffers ``storage.kept[key]`` (the tiles' spikes through
        ``storage.scratch``), which keep them."""
        empty = _empty_buffers(self.weight.dtype)
        scratch = _taken(storage.scratch, "spikes", empty[:1])[0]
        buffers = (scratch, _taken(storage.kept, key, empty))
        lists, (scratch, storage.kept[key]) = layer_forward(
            inputs, self.weight, self.geometry, self.out_pixels, self.fan,
            self.alpha, self.taps, self.refractory, (self.theta, self.half_width, record),
            buffers,
        )  # fmt: skip
        storage.scratch["spikes"] = (scratch,)
        spk_off, spk_idx, act_off, act_idx, act_u, act_tau = lists
        spikes = (spk_off, spk_idx, _ones(spk_idx.size, self.weight.dtype))
        return spikes, (act_off, act_idx, act_u), act_tau


@dataclass
class _Storage:
    """Where the pass of one batch element writes its lists: buffers kept from step to step,
    since writing fresh memory costs page faults, a large share of the pass. ``kept`` holds what
    the backward pass reads (one per batch element), ``scratch`` what is used up within one
    layer's pass (one per thread)."""

    kept: Kept
    scratch: Kept


def _empty_buffers(dtype: np.dtype) -> Buffers:
    return np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0, dtype), np.empty(0, dtype)


def _taken(store: Kept, key: str, empty: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """``store[key]`` where it holds arrays of the dtypes of ``empty`` (a model may change its
    precision between steps), else ``empty``."""
    kept = store.get(key)
    if kept is None or [a.dtype for a in kept] != [a.dtype for a in empty]:
        return empty
    return kept


_ONES: dict[np.dtype, np.ndarray] = {}


def _ones(size: int, dtype: np.dtype) -> np.ndarray:
    """``size`` ones, the values of a spike list: views of one array that is never written."""
    ones = _ONES.get(dtype)
    if ones is None or ones.size < size:
        ones = np.ones(max(size, 2 * (0 if ones is None else ones.size), 1 << 16), dtype)
        _ONES[dtype] = ones
    return ones[:size]


@dataclass
class _Element:
    """What the forward pass of one batch element keeps for its backward pass."""

    inputs: list[Lists] = field(default_factory=list)  # the input of each layer
    # per layer (offsets, indices, u) of the pairs in the support; δ over u after the backward
    active: list[tuple[np.ndarray, ...]] = field(default_factory=list)
    # per layer ∂u/∂τs, ∂u/∂τr of those pairs, interleaved (empty where τ is not learned)
    tau_sensitivity: list[np.ndarray] = field(default_factory=list)
    pooled: np.ndarray | None = None  # (features, T)
    forward_s: list[float] = field(default_factory=list)  # per layer
    backward_s: list[float] = field(default_factory=list)  # per layer, last layer first
    # weight gradients in the layers' channel blocks (channel_blocks), last layer first
    grads: list[np.ndarray] = field(default_factory=list)
    # (∂L/∂τs, ∂L/∂τr) of the layers with learned τ, last layer first
    tau_grads: list[tuple[float, float]] = field(default_factory=list)


@numba.njit(cache=True, nogil=True)
def _pool_forward(
    offsets: np.ndarray, index: np.ndarray, pooling: np.ndarray, channels: int
) -> np.ndarray:
    """(channels·cells, T) pooled spikes: feature c·cells + cell sums pooling[cell, px]·s[px, c]."""
    steps = offsets.size - 1
    cells = pooling.shape[0]
    div = divisor(channels)
    out = np.zeros((channels * cells, steps), pooling.dtype)
    for t in range(steps):
        for i in range(offsets[t], offsets[t + 1]):
            pixel = quotient(index[i], div)
            c = index[i] - pixel * channels
            for cell in range(cells):
                out[c * cells + cell, t] += pooling[cell, pixel]
    return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def _pool_deltas(
    active: tuple[np.ndarray, np.ndarray, np.ndarray],
    grad: np.ndarray,
    pooling: np.ndarray,
    surrogate: np.ndarray,
) -> None:
    """δ = ρ(u)·∂L/∂s of the last layer at its pairs (offsets (tiles, T + 1), index, u), from
    ∂L/∂pooled (features, T), written over u."""
    offsets, index, u = active
    cells, channels = pooling.shape[0], grad.shape[0] // pooling.shape[0]
    div = divisor(channels)
    zero = np.zeros(1, grad.dtype)[0]  # a literal 0 would make the sum float64
    for t in range(offsets.shape[1] - 1):
        for s in range(offsets.shape[0]):
            for i in range(offsets[s, t], offsets[s, t + 1]):
                pixel = quotient(index[i], div)
                c = index[i] - pixel * channels
                total = zero
                for cell in range(cells):
                    total += pooling[cell, pixel] * grad[c * cells + cell, t]
                u[i] = surrogate_pdf(u[i], surrogate) * total


def _element_inputs(x: torch.Tensor) -> tuple[list[np.ndarray | Lists], list[float]]:
    """Each batch element's input, as the engine's lists for a sparse (N, C, H, W, T) tensor or
    as a dense (C, H, W, T) array, and its cost: its number of input entries, or its sum (which
    orders the elements as well, and costs less than counting a dense tensor's non-zeros)."""
    x = x.detach().cpu()
    if not x.is_sparse:
        return list(x.numpy()), x.flatten(1).sum(1).tolist()
    offsets, index, values = coo_to_lists(
        x._indices().numpy(), x._values().numpy(), tuple(int(n) for n in x.shape)
    )
    lists: list[np.ndarray | Lists] = [
        (o - o[0], index[o[0] : o[-1]], values[o[0] : o[-1]]) for o in offsets
    ]
    return lists, [float(o[-1] - o[0]) for o in offsets]


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
        threads: threads that run the layers of the batch elements (:meth:`_stages`).
    """

    def __init__(self, convs: Sequence[SRMConv], pool: nn.Module, threads: int = 1) -> None:
        self.convs = tuple(convs)
        self.pool = pool
        self.threads = max(1, int(threads))
        self.timing = SparseTiming()
        # Buffers of the last steps, reused (_Storage): per batch element, what a pass keeps
        # until its backward pass, and per thread, its scratch. A pass takes them from here and
        # gives them back when it is done with them (list.pop and append are atomic).
        self._kept: list[Kept] = []
        self._scratch: list[Kept] = []

    def __getstate__(self) -> dict[str, Any]:
        """A copy (deepcopy, pickle) starts without the buffers."""
        return {**self.__dict__, "_kept": [], "_scratch": []}

    def pooled(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled last-layer spikes (N, features, T) of input (N, C, H, W, T) (time last, 1 ms),
        dense or a sparse COO tensor (the engine reads its entries, never a dense copy)."""
        weights = [conv.weight for conv in self.convs]
        taus = [
            tau for conv in self.convs if conv.learn_tau for tau in (conv.tau_s(), conv.tau_r())
        ]
        if torch.is_grad_enabled() and any(w.requires_grad for w in weights + taus):
            return _EventDrivenFunction.apply(self, x, *weights, *taus)
        return self._forward(x, record=False)[0]

    def _forward(self, x: torch.Tensor, record: bool) -> tuple[torch.Tensor, _Plan]:
        weight = self.convs[0].weight
        dtype = np.float64 if weight.dtype == torch.float64 else np.float32
        plan = _Plan.of(self.convs, self.pool, tuple(x.shape[2:4]), dtype, record)
        start = time.perf_counter()
        sources, costs = _element_inputs(x)
        plan.kept = [self._kept.pop() if self._kept else {} for _ in costs]
        plan.elements = [_Element() for _ in costs]
        self._stages(
            len(plan.layers),
            lambda b, i, scratch: plan.forward_layer(
                plan.elements[b], i, _Storage(plan.kept[b], scratch), sources[b]
            ),
            costs,
        )
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
        if not record:
            self._give_back(plan)
        return torch.from_numpy(pooled).to(device=x.device, dtype=weight.dtype), plan

    def _give_back(self, plan: _Plan) -> None:
        """Return the plan's buffers for reuse; its lists are not to be read after this."""
        self._kept.extend(plan.kept)
        del self._kept[len(plan.kept) :]  # two passes in flight: keep one batch's worth
        plan.kept = []

    def _backward(self, plan: _Plan, grad_pooled: torch.Tensor) -> list[torch.Tensor | None]:
        start = time.perf_counter()
        grad_np = grad_pooled.detach().cpu().numpy().astype(plan.dtype)
        costs = [sum(a[1].size for a in e.active) for e in plan.elements]
        last = len(plan.layers) - 1
        self._stages(
            len(plan.layers) - plan.first,
            lambda b, k, _: plan.backward_layer(plan.elements[b], last - k, grad_np[b]),
            costs,
        )
        per_element = [e.grads[::-1] for e in plan.elements]
        self.timing.backward_s = time.perf_counter() - start
        self._give_back(plan)
        per_layer = np.sum([e.backward_s[::-1] for e in plan.elements], axis=0)
        self.timing.layer_backward_s = [0.0] * plan.first + per_layer.tolist()
        grads: list[torch.Tensor | None] = [None] * plan.first
        for i, conv in enumerate(self.convs[plan.first :]):
            total = per_element[0][i].copy()
            for element in per_element[1:]:
                total += element[i]
            flat = unblocked(total)  # (kh·kw, in, out)
            shaped = flat.reshape(*conv.weight.shape[2:], *flat.shape[1:])  # (kh, kw, in, out)
            grads.append(torch.from_numpy(shaped).permute(3, 2, 0, 1).contiguous().to(conv.weight))
        return grads + self._tau_grads(plan)

    def _tau_grads(self, plan: _Plan) -> list[torch.Tensor | None]:
        """[∂L/∂τs, ∂L/∂τr] of every layer with learned τ, in order (None below ``first``),
        summed over the batch."""
        learned = [i for i, conv in enumerate(self.convs) if conv.learn_tau]
        totals = np.sum([e.tau_grads[::-1] for e in plan.elements], axis=0)  # from plan.first
        grads: list[torch.Tensor | None] = []
        for i in learned:
            if i < plan.first:
                grads += [None, None]
                continue
            grads += [torch.tensor(float(v), dtype=torch.float64) for v in totals[i - plan.first]]
        return grads

    def _stages(
        self, stages: int, fn: Callable[[int, int, Kept], None], costs: Sequence[float]
    ) -> None:
        """fn(b, k, scratch) for every batch element b and stage k < ``stages``, stage k of an
        element after its stage k − 1, on ``threads`` threads; ``scratch``: buffers no other
        thread uses meanwhile.

        A free thread takes the lowest stage that is ready, of the costliest element (by
        ``costs``) among them. The stages of an element (its layers) must run in order, but
        those of different elements need not: taken by whole elements, two threads ended up to
        a fifth of a pass apart (the last element's layers ran alone); taken by stages, what is
        left at the end are the short last stages of a few elements.
        """
        order = sorted(range(len(costs)), key=lambda b: -costs[b])
        ready = [(0, rank, b) for rank, b in enumerate(order)]  # a heap
        remaining, failed = stages * len(order), False
        cond = threading.Condition()

        def wake() -> bool:  # a task is ready, or there will be none
            return bool(ready) or not remaining or failed

        def work() -> None:
            nonlocal remaining, failed
            scratch = self._scratch.pop() if self._scratch else {}
            try:
                while True:
                    with cond:
                        cond.wait_for(wake)
                        if failed or not ready:
                            return
                        k, rank, b = heapq.heappop(ready)
                    try:
                        fn(b, k, scratch)
                    except BaseException:
                        with cond:
                            failed = True
                            cond.notify_all()
                        raise
                    with cond:
                        remaining -= 1
                        if k + 1 < stages:
                            heapq.heappush(ready, (k + 1, rank, b))
                        cond.notify_all()
            finally:
                self._scratch.append(scratch)

        threads = min(self.threads, len(order))
        if threads <= 1:
            work()
            return
        with ThreadPoolExecutor(threads) as workers:
            for done in [workers.submit(work) for _ in range(threads)]:
                done.result()


class _EventDrivenFunction(torch.autograd.Function):
    """Autograd node of :meth:`EventDrivenStack.pooled`: the conv weights' gradients come from
    the event-driven backward pass."""

    @staticmethod
    def forward(ctx, engine: EventDrivenStack, x: torch.Tensor, *weights_and_taus: torch.Tensor):
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
    first: int  # the first layer whose weight or τ learns (len(layers): none)
    pooling: np.ndarray
    dtype: type
    elements: list[_Element] = field(default_factory=list)
    kept: list[Kept] = field(default_factory=list)  # per element

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
            tau = record and conv.learn_tau and conv.tau_s_param.requires_grad
            layers.append(_Layer.of(conv, size, dtype, tau))
            size = layers[-1].out_shape
        trainable = [record and any(p.requires_grad for p in conv.parameters()) for conv in convs]
        first = trainable.index(True) if any(trainable) else len(convs)
        pooling = pooling_matrix(pool, *size, convs[0].weight.dtype).astype(dtype)
        return cls(layers, first, pooling, dtype)

    @property
    def channels(self) -> int:
        return self.layers[-1].out_channels

    def forward_element(self, x: np.ndarray | Lists, storage: _Storage | None = None) -> _Element:
        """Forward pass of one (C, H, W, T) input (or its lists); keeps each layer's input and
        active pairs (in ``storage``: buffers of earlier steps to reuse, or new ones)."""
        storage = storage or _Storage({}, {})
        element = _Element()
        for i in range(len(self.layers)):
            self.forward_layer(element, i, storage, x)
        return element

    def forward_layer(
        self, element: _Element, i: int, storage: _Storage, x: np.ndarray | Lists
    ) -> None:
        """Layer i of :meth:`forward_element` (layers 0 … i − 1 done): the input's lists come
        from ``x`` (dense (C, H, W, T), or its lists) before the first layer, the pooled spikes
        after the last."""
        if i == 0:
            offsets, index, values = (
                x if isinstance(x, tuple) else dense_to_lists(np.ascontiguousarray(x))
            )
            element.inputs.append((offsets, index, values.astype(self.dtype, copy=False)))
        start = time.thread_time()
        spikes, active, sensitivity = self.layers[i].forward(
            element.inputs[i], i >= self.first, storage, f"layer{i}"
        )
        element.forward_s.append(time.thread_time() - start)
        element.active.append(active)
        element.tau_sensitivity.append(sensitivity)
        if i + 1 < len(self.layers):
            element.inputs.append(spikes)
        else:
            element.pooled = _pool_forward(spikes[0], spikes[1], self.pooling, self.channels)

    def backward_element(self, element: _Element, grad_pooled: np.ndarray) -> list[np.ndarray]:
        """Weight gradients (kh·kw, C_in, C_out) of layers ``first`` … last for one element; the
        element's active potentials are overwritten with δ."""
        for i in range(len(self.layers) - 1, self.first - 1, -1):
            self.backward_layer(element, i, grad_pooled)
        return [unblocked(grad) for grad in element.grads[::-1]]

    def backward_layer(self, element: _Element, i: int, grad_pooled: np.ndarray) -> None:
        """Layer i of :meth:`backward_element` (layers above it done): its weight gradient, and
        the δ of the layer below over their potentials (of the last layer first, from
        ∂L/∂pooled)."""
        layer = self.layers[i]
        start = time.thread_time()
        if i == len(self.layers) - 1:
            _pool_deltas(element.active[i], grad_pooled, self.pooling, layer.surrogate)
        element.tau_grads.append(tau_gradient(element.active[i][2], element.tau_sensitivity[i]))
        lower = max(i - 1, 0)  # the layer below, whose δ are wanted above ``first``
        wanted = i > self.first
        below = element.active[lower] if wanted else tuple(a[:0] for a in element.active[i])
        grad_w = layer_backward(
            element.active[i], layer.alpha, layer.taps, element.inputs[i], layer.weight,
            layer.fan, layer.out_pixels, (below, self.layers[lower].surrogate),
        )  # fmt: skip
        element.grads.append(grad_w)
        element.backward_s.append(time.thread_time() - start)
