"""Event-driven backward pass of one SRM conv layer on the CPU (Numba).

With a bounded surrogate, δ[t] = ∂L/∂u[t] = ρ(u)·∂L/∂s[t] is non-zero only at the (neuron, step)
pairs that :func:`spikegyro.snn.sparse_forward.layer_forward` recorded within the support. From
those δ alone, in reverse time (no gradient flows through the refractory feedback, as in SLAYER):

- PSP adjoint: ∂L/∂z[t] = Σ_{k≥1} ε[k]·δ[t + k]. In reverse time this is the causal filter of
  the forward pass, so it runs as the same double pole (A, D) with each δ fed in once and once
  more, L steps earlier, with the tail weights (the truncation of ε, exactly)::

      A[t] = p·A[t+1] + δ[t] − pᴸ·δ[t+L]
      D[t] = p·D[t+1] + p·A[t+1] − L·pᴸ·δ[t+L]          ∂L/∂z[t] = c·D[t]

  advanced over runs of live pixels (those with a δ in the next L − 1 steps) in one vectorised
  loop; a pixel whose last δ has left the kernel has its state and ∂L/∂z set to exactly 0;
- weight gradient: ∂L/∂W[tap, c, :] += value·∂L/∂z[t, pixel, :] for every input spike (or input
  value) at step t and every live output pixel it reaches: the transpose of the forward scatter,
  from sparse inputs only;
- input gradient: ∂L/∂s_in[t] = convᵀ(∂L/∂z[t]), evaluated only at the pairs of the layer below
  that lie within *its* support (elsewhere its ρ is 0 and the value is never used), and turned
  at once into that layer's δ = ρ(u)·∂L/∂s_in, written over the potentials u the forward pass
  recorded (so the backward pass needs no buffers of its own per pair); the pairs of one input
  pixel share their targets.

In both products the row of ∂L/∂z that the entries of one input pixel share stays in vector
registers across them (:func:`spikegyro.snn.simd.add_scaled`, :func:`spikegyro.snn.simd.dot_rows`).

Layouts as in :mod:`spikegyro.snn.sparse_forward` (channels-last flat indices, CSR by step).
Sums run in any order (``fastmath``): they are not compared with a threshold.
"""

from __future__ import annotations

import numba
import numpy as np

from spikegyro.snn.simd import add_scaled, dot_rows
from spikegyro.snn.sparse_forward import divisor, pixel_group, quotient

_FUTURE = np.iinfo(np.int64).max


@numba.njit(cache=True, nogil=True, fastmath=True)
def surrogate_pdf(u: float, surrogate: np.ndarray) -> float:
    """ρ(u) = scale_rho/θ·exp(−|u − θ|/(tau_rho·θ)); surrogate = [θ, scale_rho/θ,
    −1/(tau_rho·θ)] (potential units)."""
    return surrogate[1] * np.exp(surrogate[2] * abs(u - surrogate[0]))


@numba.njit(cache=True, nogil=True)
def tau_gradient(delta: np.ndarray, sensitivity: np.ndarray) -> tuple[float, float]:
    """(∂L/∂τs, ∂L/∂τr) of a layer: Σ_j δ_j·∂u_j/∂τs and Σ_j δ_j·∂u_j/∂τr over its active pairs
    j, from δ = ∂L/∂u and the derivatives interleaved in ``sensitivity`` ([2j], [2j + 1]), as
    :func:`spikegyro.snn.sparse_forward.layer_forward` records them with learned τ (empty:
    zeros); summed in float64. Elsewhere ρ(u) = 0, so δ = 0 and the pairs add nothing."""
    grad_s, grad_r = 0.0, 0.0
    if sensitivity.size:
        for j in range(delta.size):
            d = np.float64(delta[j])
            grad_s += d * sensitivity[2 * j]
            grad_r += d * sensitivity[2 * j + 1]
    return grad_s, grad_r


@numba.njit(cache=True, nogil=True, fastmath=True)
def _enter(
    state: np.ndarray,
    index: np.ndarray,
    delta: np.ndarray,
    span: tuple[int, int],
    live: np.ndarray,
    until: int,
) -> None:
    """A += δ at the pairs ``span`` (start, stop), whose pixels stay live down to step ``until``
    (a new δ; steps only decrease). D is left alone: δ enters the double pole through A only."""
    div = divisor(state.shape[1] // live.size)
    for j in range(span[0], span[1]):
        state[0, index[j]] += delta[j]
        live[quotient(index[j], div)] = until


@numba.njit(cache=True, nogil=True, fastmath=True)
def _leave(
    state: np.ndarray, index: np.ndarray, delta: np.ndarray, span: tuple[int, int], tail: np.ndarray
) -> None:
    """A += −pᴸ·δ, D += −L·pᴸ·δ (tail = [−pᴸ, −L·pᴸ]) at the pairs ``span``: their δ leave the
    truncated kernel."""
    for j in range(span[0], span[1]):
        state[0, index[j]] += tail[0] * delta[j]
        state[1, index[j]] += tail[1] * delta[j]


@numba.njit(cache=True, nogil=True, fastmath=True)
def _adjoint_step(
    state: np.ndarray, grad_z: np.ndarray, live: np.ndarray, t: int, alpha: np.ndarray
) -> None:
    """∂L/∂z[t] = c·D[t] at every live pixel (runs of adjacent ones, one vectorised loop each) and
    one reverse step of the recursion; a pixel whose δ have all left the kernel (``live`` = t) is
    cleared, and stays so while ``live`` > t."""
    c_eps, p_eps = alpha[0], alpha[1]
    cout = grad_z.size // live.size
    pixel = 0
    while pixel < live.size:
        if live[pixel] > t:
            pixel += 1
            continue
        if live[pixel] == t:  # exactly 0 from here on: the kernel is truncated
            lo, hi = pixel * cout, (pixel + 1) * cout
            state[:, lo:hi] = 0.0
            grad_z[lo:hi] = 0.0
            pixel += 1
            continue
        end = pixel + 1
        while end < live.size and live[end] < t:
            end += 1
        a, d = state[0, pixel * cout : end * cout], state[1, pixel * cout : end * cout]
        g = grad_z[pixel * cout : end * cout]
        for o in range(g.size):  # a = p·A[t+1], d = p·(D[t+1] + A[t+1]) and the δ of step t
            dd = d[o]
            aa = a[o]
            g[o] = c_eps * dd
            d[o] = p_eps * (dd + aa)
            a[o] = p_eps * aa
        pixel = end


@numba.njit(cache=True, nogil=True, inline="always")
def _live_tap(
    pairs: np.ndarray, k: int, live: np.ndarray, t: int, cout: int, offset: int
) -> tuple[int, int]:
    """(tap, where ∂L/∂z[pixel, offset:] begins in the flat array) of fan-out entry k (pairs:
    the fan-out table's (2, n) pixels and taps); −1 where ∂L/∂z is exactly 0 at the pixel."""
    pixel, tap = pairs[0, k], pairs[1, k]
    return tap, (-1 if live[pixel] >= t else pixel * cout + offset)


@numba.njit(cache=True, nogil=True, fastmath=True)
def _weight_grad_at(
    grad_w: np.ndarray,
    grad_z: np.ndarray,
    live: np.ndarray,
    t: int,
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray],
    fan: tuple[np.ndarray, np.ndarray],
) -> None:
    """∂W[tap, c, :] += value·∂L/∂z[pixel, :] for the inputs of step t, one block of output
    channels after the other (grad_w: (blocks, kh·kw, C_in, C_out / blocks))."""
    offsets, index, values = inputs
    blocks, cin, width = grad_w.shape[0], grad_w.shape[2], grad_w.shape[3]
    cout = blocks * width
    div = divisor(cin)
    for block in range(blocks):
        i, stop = offsets[t], offsets[t + 1]
        while i < stop:
            pixel_in, end = pixel_group(index, i, stop, cin, div)
            for k in range(fan[0][pixel_in], fan[0][pixel_in + 1]):
                tap, first = _live_tap(fan[1], k, live, t, cout, block * width)
                if first >= 0:
                    grad = grad_z[first : first + width]
                    add_scaled(grad_w[block, tap], grad, index, values, (i, end), pixel_in * cin)
            i = end


@numba.njit(cache=True, nogil=True, fastmath=True)
def _input_deltas_at(
    weight: np.ndarray,
    grad_z: np.ndarray,
    live: np.ndarray,
    t: int,
    below: tuple[np.ndarray, np.ndarray, np.ndarray],
    surrogate: np.ndarray,
    fan: tuple[np.ndarray, np.ndarray],
    partial: np.ndarray,
) -> None:
    """δ = ρ(u)·convᵀ(∂L/∂z[t])[index[j]] of the layer below at its pairs of step t (offsets
    (tiles, T + 1): a range per tile), written over their potentials u; surrogate: the layer
    below's (:func:`surrogate_pdf`); weight: (blocks, kh·kw, C_in, C_out / blocks), the blocks
    one after the other, their sums in ``partial`` (as long as the longest range)."""
    offsets, index, u = below
    blocks, cin, width = weight.shape[0], weight.shape[2], weight.shape[3]
    cout = blocks * width
    div = divisor(cin)
    for s in range(offsets.shape[0]):
        lo, stop = offsets[s, t], offsets[s, t + 1]
        partial[: stop - lo] = 0.0
        for block in range(blocks):
            i = lo
            while i < stop:
                pixel_in, end = pixel_group(index, i, stop, cin, div)
                for k in range(fan[0][pixel_in], fan[0][pixel_in + 1]):
                    tap, first = _live_tap(fan[1], k, live, t, cout, block * width)
                    if first >= 0:
                        grad = grad_z[first : first + width]
                        dot_rows(partial[i - lo :], weight[block, tap], index, grad, (i, end),
                                 pixel_in * cin)  # fmt: skip
                i = end
        for e in range(lo, stop):
            u[e] = surrogate_pdf(u[e], surrogate) * partial[e - lo]


@numba.njit(cache=True, nogil=True)
def layer_backward(
    active: tuple[np.ndarray, np.ndarray, np.ndarray],
    alpha: np.ndarray,
    taps: int,
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray],
    weight: np.ndarray,
    fan: tuple[np.ndarray, np.ndarray],
    out_pixels: int,
    below: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
) -> np.ndarray:
    """Weight gradient of one layer, and δ of the layer below at its active pairs.

    Args:
        active: (offsets (tiles, T + 1), flat indices, δ) of this layer's pairs within the
            surrogate's support, as :func:`spikegyro.snn.sparse_forward.layer_forward` gives
            them, with δ = ∂L/∂u written over their potentials.
        alpha, taps: the PSP kernel ε[k] = c·k·pᵏ, k < L = ``taps`` steps
            (:func:`spikegyro.snn.sparse_forward.alpha_constants`).
        inputs: (offsets, flat indices, values) of this layer's input, as in the forward pass.
        weight: (blocks, kh·kw, C_in, C_out / blocks)
            (:func:`spikegyro.snn.sparse_forward.channel_blocks`); fan, out_pixels: as in the
            forward pass.
        below: ((offsets (tiles, T + 1), flat indices, potentials u) of the active pairs of the
            layer below (the input side), the layer below's surrogate (:func:`surrogate_pdf`)):
            its δ are written over u; an empty index list when they are not wanted.

    Returns:
        ∂L/∂W in the blocks of ``weight``.
    """
    act_offsets, act_index, delta = active
    steps = act_offsets.shape[1] - 1
    cout = weight.shape[0] * weight.shape[3]
    below_offsets = below[0][0]
    longest = (below_offsets[:, 1:] - below_offsets[:, :-1]).max() if below_offsets.size else 0
    partial = np.empty(longest, weight.dtype)  # one range of pairs' ∂L/∂s over the blocks
    grad_w = np.zeros_like(weight)
    state = np.zeros((2, out_pixels * cout), weight.dtype)
    grad_z = np.zeros(out_pixels * cout, weight.dtype)
    # Per pixel, the step at which its last δ leaves the kernel (the state is cleared there);
    # ∂L/∂z may be non-zero only at the steps above it, back to the last δ ("never": _FUTURE).
    live = np.full(out_pixels, _FUTURE, np.int64)
    for t in range(steps - 1, -1, -1):
        for s in range(act_offsets.shape[0]):
            if t + taps < steps:  # the δ of step t + L leave the kernel
                span = (act_offsets[s, t + taps], act_offsets[s, t + taps + 1])
                _leave(state, act_index, delta, span, alpha[2:4])
            _enter(state, act_index, delta, (act_offsets[s, t], act_offsets[s, t + 1]), live,
                   t - taps)  # fmt: skip
        _adjoint_step(state, grad_z, live, t, alpha)
        _weight_grad_at(grad_w, grad_z, live, t, inputs, fan)
        if below[0][1].size:
            _input_deltas_at(weight, grad_z, live, t, below[0], below[1], fan, partial)
    return grad_w
