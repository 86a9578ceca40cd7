"""Triton kernels for the SRM spike recursion: one launch per layer instead of ~3 per step.

:func:`spikegyro.snn.functional.spike_fn` uses these on CUDA tensors (float32) when Triton is
installed (``pip install spikegyro[gpu]``); everywhere else the torch code in
:mod:`spikegyro.snn.functional` runs. Set ``SPIKEGYRO_TRITON=0`` to force the torch code on CUDA
too (for comparisons). With ``TRITON_INTERPRET=1`` set before this module is imported, Triton's
interpreter runs the same kernels on CPU tensors (slowly): that is how the tests check them
without a GPU.

Forward (:func:`fire_rows`): each program owns a block of neurons (columns of a (T, M) potential)
and walks the T steps; a neuron's last ≤ 63 spikes live in a bit mask in registers, so the
refractory responses Σ_k ν[k]·s[t − k] cost no memory traffic. They are added oldest spike first,
as the torch code's ``addcmul_`` sequence adds them, so potentials and spikes are bit-identical
to it. Backward (:func:`surrogate_backward`): ρ(u)·grad in one pass instead of five.
"""

from __future__ import annotations

import os

import torch
import triton
import triton.language as tl

BLOCK = 256
"""Neurons per program on a GPU."""

INTERPRETER_BLOCK = 8192
"""Neurons per program under the interpreter, which runs programs one after another (each as
NumPy array operations), so fewer, larger programs are much faster."""

MAX_TAPS = 64
"""Longest refractory kernel (taps, including ν[0] = 0) the bit-mask history holds."""


def enabled_for(x: torch.Tensor, ref_kernel: torch.Tensor | None = None) -> bool:
    """Whether the Triton kernels handle ``x``: float32 on CUDA (or anywhere under the
    interpreter), unless ``SPIKEGYRO_TRITON=0``, with a refractory kernel they can hold."""
    if os.environ.get("SPIKEGYRO_TRITON", "1") == "0" or x.dtype != torch.float32:
        return False
    if ref_kernel is not None and ref_kernel.numel() > MAX_TAPS:
        return False
    return x.is_cuda or os.environ.get("TRITON_INTERPRET", "0") == "1"


@triton.jit
def _fire_kernel(
    u_ptr,
    pot_ptr,
    spk_ptr,
    nu_ptr,
    theta,
    steps,
    m,
    stride_ut,
    stride_um,
    TAPS: tl.constexpr,
    BLOCK_M: tl.constexpr,
):
    cols = tl.program_id(0) * BLOCK_M + tl.arange(0, BLOCK_M)
    mask = cols < m
    history = tl.zeros((BLOCK_M,), dtype=tl.int64)  # bit k-1: spike k steps ago
    u_ptrs = u_ptr + cols.to(tl.int64) * stride_um  # 64-bit offsets: no overflow at any batch
    out = cols.to(tl.int64)
    for _ in range(0, steps):
        u = tl.load(u_ptrs, mask=mask, other=0.0)
        for k in tl.static_range(TAPS - 1, 0, -1):  # oldest spike first, as the torch code
            fired = ((history >> (k - 1)) & 1).to(tl.float32)
            u = u + tl.load(nu_ptr + k) * fired
        spike = u >= theta
        tl.store(pot_ptr + out, u, mask=mask)
        tl.store(spk_ptr + out, spike.to(tl.float32), mask=mask)
        u_ptrs += stride_ut
        out += m
        history = (history << 1) | spike.to(tl.int64)


def fire_rows(
    rows: torch.Tensor, theta: float, ref_kernel: torch.Tensor, *, in_place: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Spike recursion on a (T, M) float32 potential; returns (spikes, potential with ν added).

    Same contract as :func:`spikegyro.snn.functional._fire_rows` (whose validation of
    ``ref_kernel`` has run): ``rows`` may be any 2-D strided view; ``in_place`` writes the
    potential into ``rows`` (which must then be contiguous).
    """
    steps, m = rows.shape
    potential = rows if in_place else torch.empty((steps, m), dtype=rows.dtype, device=rows.device)
    spikes = torch.empty((steps, m), dtype=rows.dtype, device=rows.device)
    if rows.numel() == 0:
        return spikes, potential
    nu = ref_kernel.to(device=rows.device, dtype=torch.float32).contiguous()
    block = BLOCK if rows.is_cuda else INTERPRETER_BLOCK
    _fire_kernel[(triton.cdiv(m, block),)](
        rows, potential, spikes, nu, float(theta), steps, m, rows.stride(0), rows.stride(1),
        TAPS=nu.numel(), BLOCK_M=block,
    )  # fmt: skip
    return spikes, potential


@triton.jit
def _surrogate_kernel(
    pot_ptr, grad_ptr, out_ptr, n, theta, inv_width, height, BLOCK_N: tl.constexpr
):
    offsets = tl.program_id(0).to(tl.int64) * BLOCK_N + tl.arange(0, BLOCK_N)
    mask = offsets < n
    u = tl.load(pot_ptr + offsets, mask=mask, other=0.0)
    g = tl.load(grad_ptr + offsets, mask=mask, other=0.0)
    rho = tl.exp(tl.abs(u - theta) * inv_width) * height
    tl.store(out_ptr + offsets, rho * g, mask=mask)


def surrogate_backward(
    potential: torch.Tensor, grad: torch.Tensor, theta: float, scale_rho: float, tau_rho: float
) -> torch.Tensor:
    """ρ(u)·grad (see :func:`spikegyro.snn.functional.surrogate_gradient`), one fused pass."""
    potential, grad = potential.contiguous(), grad.contiguous()
    out = torch.empty_like(potential)
    n = potential.numel()
    if n:
        block = 1024 if potential.is_cuda else INTERPRETER_BLOCK
        _surrogate_kernel[(triton.cdiv(n, block),)](
            potential, grad, out, n, float(theta), -1.0 / (tau_rho * theta), scale_rho / theta,
            BLOCK_N=block,
        )  # fmt: skip
    return out
