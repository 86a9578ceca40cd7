"""Event-driven forward pass of one SRM conv layer on the CPU (Numba), keeping what training needs.

The layer computes, step by step (Ts = 1 ms), exactly what :class:`spikegyro.snn.layers.SRMConv`
computes in batch: ``z[t] = conv(s_in[t])``, ``v[t] = Σ_k ε[k]·z[t − k]``, ``u[t] = v[t] +
Σ_k ν[k]·s_out[t − k]``, ``s_out[t] = u[t] ≥ θ``. It touches only what the input spikes reach:

- the PSP runs on the output side as the double pole ``(A, D)`` of the truncated alpha kernel
  ε[k] = c·k·pᵏ (k < L), with each input fed a second time L steps later with the tail weights,
  so that the response is exactly 0 from k = L on (the same recursion as
  :mod:`spikegyro.stream.stateful`)::

      A[t] = p·A[t−1] + z[t] − pᴸ·z[t−L]
      D[t] = p·D[t−1] + p·A[t−1] − L·pᴸ·z[t−L]          v[t] = c·D[t]

- the refractory responses ν[1 … M−1] of each output spike are added into a ring of M future
  potential maps (the batch path adds the same taps to the same future rows);
- a pixel (all output channels at one position) is visited only while some input of the last
  L steps or some own spike of the last M−1 steps may still act on it; when its last input has
  expired its state is set to exactly 0.

Besides the output spike lists, the pass records every (neuron, step) pair whose potential lies
within the surrogate's support, |u − θ| ≤ half-width, with u: the only pairs where the backward
pass (:mod:`spikegyro.snn.sparse_backward`) has a non-zero ρ(u). The half-width must be < θ (the
cut above exp(−1/tau_rho) of the peak), so that a neuron at rest (u = 0) is never such a pair.

Spike lists are CSR by step: ``offsets`` (T + 1,) int64 and flat neuron indices
``(y·W + x)·C + c`` (int32), channels-last like the weights ``(kh, kw, C_in, C_out)``.
"""

from __future__ import annotations

import numba
import numpy as np

_MIN_CAPACITY = 1024


@numba.njit(cache=True, nogil=True)
def _grow(array: np.ndarray, size: int) -> np.ndarray:
    """``array`` if it holds more than ``size`` entries, else a copy twice as large."""
    if size < array.size:
        return array
    bigger = np.empty(max(2 * array.size, _MIN_CAPACITY), array.dtype)
    bigger[: array.size] = array
    return bigger


@numba.njit(cache=True, nogil=True)
def dense_to_lists(
    x: np.ndarray, threshold: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input lists of a (C, H, W, T) tensor: (offsets (T + 1,), flat (y·W + x)·C + c, values).

    Entries with |value| <= ``threshold`` (exact zeros by default) are left out.
    """
    channels, height, width, steps = x.shape
    counts = np.zeros(steps + 1, np.int64)
    for c in range(channels):
        for y in range(height):
            for xx in range(width):
                row = x[c, y, xx]
                for t in range(steps):
                    if abs(row[t]) > threshold:
                        counts[t + 1] += 1
    offsets = np.cumsum(counts)
    fill = offsets[:-1].copy()
    index = np.empty(offsets[-1], np.int32)
    values = np.empty(offsets[-1], x.dtype)
    for y in range(height):
        for xx in range(width):
            for c in range(channels):
                row = x[c, y, xx]
                flat = (y * width + xx) * channels + c
                for t in range(steps):
                    if abs(row[t]) > threshold:
                        index[fill[t]] = flat
                        values[fill[t]] = row[t]
                        fill[t] += 1
    return offsets, index, values


@numba.njit(cache=True, nogil=True)
def fanout_tables(
    in_size: int, out_size: int, kernel: int, stride: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per input row (or column) i: the first and last output o with 0 <= i − o·stride < kernel
    (no padding), clipped to the map; an empty range (first > last) when none."""
    first = np.empty(in_size, np.int64)
    last = np.empty(in_size, np.int64)
    for i in range(in_size):
        first[i] = max(0, (i - kernel + stride) // stride)
        last[i] = min(out_size - 1, i // stride)
    return first, last


@numba.njit(cache=True, nogil=True)
def _scatter(
    synaptic: np.ndarray,
    live: np.ndarray,
    live_until: int,
    index: np.ndarray,
    values: np.ndarray,
    start: int,
    stop: int,
    weight: np.ndarray,
    stride: int,
    in_width: int,
    out_width: int,
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
) -> None:
    """Add ``value·W[ky, kx, c, :]`` to the synaptic input map of every output pixel each input
    ``start:stop`` reaches (the convolution as a scatter from its non-zero inputs)."""
    kernel_w, cin, cout = weight.shape[1], weight.shape[2], weight.shape[3]
    for i in range(start, stop):
        pixel_in, c = divmod(index[i], cin)
        iy, ix = divmod(pixel_in, in_width)
        value = values[i]
        for oy in range(rows[0][iy], rows[1][iy] + 1):
            ky = iy - oy * stride
            for ox in range(cols[0][ix], cols[1][ix] + 1):
                kx = ix - ox * stride
                if kx >= kernel_w:
                    continue
                pixel = oy * out_width + ox
                # Slice views let LLVM vectorise the loop (no wrap-around checks on indices).
                target = synaptic[pixel * cout : (pixel + 1) * cout]
                w = weight[ky, kx, c]
                for o in range(cout):
                    target[o] += value * w[o]
                live[pixel] = max(live[pixel], live_until)


def alpha_constants(kernel: np.ndarray, dtype: type) -> tuple[np.ndarray, int]:
    """([c, p, 1, −pᴸ, −L·pᴸ] in ``dtype``, L) for the truncated PSP taps ε[k] = c·k·pᵏ, k < L.

    c = ε[1]/p and p = ε[2]/(2·ε[1]) from the first taps (computed in float64 from taps exact to
    the last bit of a double they give c = e/τs and p = exp(−1/τs) to rounding); the rest of the
    taps is checked against them.
    """
    taps = np.asarray(kernel, dtype=np.float64)
    if taps.size < 3 or taps[0] != 0 or taps[1] <= 0:
        raise ValueError(f"PSP kernel: expected c·k·p^k with at least 3 taps, got {taps[:4]}")
    p = taps[2] / (2.0 * taps[1])
    c = taps[1] / p
    k = np.arange(taps.size)
    if not np.allclose(taps, c * k * p**k, rtol=1e-5, atol=1e-7):
        raise ValueError("PSP kernel: taps are not of the form c·k·p^k")
    size = taps.size
    consts = np.array([c, p, 1.0, -(p**size), -size * p**size], dtype=dtype)
    return consts, size


@numba.njit(cache=True, nogil=True)
def layer_forward(
    in_offsets: np.ndarray,
    in_index: np.ndarray,
    in_values: np.ndarray,
    in_width: int,
    weight: np.ndarray,
    stride: int,
    out_shape: tuple[int, int],
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
    alpha: np.ndarray,
    taps: int,
    ref_taps: np.ndarray,
    theta: float,
    half_width: float,
    record: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Run one layer over all steps; see the module docstring.

    Args:
        in_offsets, in_index, in_values: the input lists (CSR by step; values multiply W).
        in_width: input map width, px.
        weight: (kh, kw, C_in, C_out), the dtype of the computation (float32 or float64).
        out_shape: (height, width) of the output map; rows, cols: :func:`fanout_tables`.
        alpha: [c, p, 1, −pᴸ, −L·pᴸ] of the PSP kernel ε[k] = c·k·pᵏ for k < L = ``taps``
            (steps), in the weight's dtype (:func:`alpha_constants`).
        ref_taps: ν[0 … M−1] (ν[0] = 0), potential units, in the weight's dtype.
        theta, half_width: threshold and the surrogate's support |u − θ| <= half_width, as
            scalars of the weight's dtype: the comparisons are then made in that precision,
            as the batch path makes them.
        record: keep the pairs within the support (only a layer that back-propagates needs them).

    Returns:
        (spike offsets, spike indices, active offsets, active indices, active potentials u).
    """
    steps = in_offsets.size - 1
    cout = weight.shape[3]
    out_height, out_width = out_shape
    pixels = out_height * out_width
    dtype = weight.dtype
    c_eps, p_eps, tail_a, tail_d = alpha[0], alpha[1], alpha[3], alpha[4]
    state_a = np.zeros(pixels * cout, dtype)
    state_d = np.zeros(pixels * cout, dtype)
    # z[t] of the last L + 1 steps: z[t − L] leaves the PSP through the tail weights.
    synaptic = np.zeros((taps + 1, pixels * cout), dtype)
    ring_len = ref_taps.size
    ring = np.zeros((ring_len, pixels * cout), dtype)
    potential = np.empty(cout, dtype)
    live = np.full(pixels, -1, np.int64)
    spike_offsets = np.zeros(steps + 1, np.int64)
    spikes = np.empty(_MIN_CAPACITY, np.int32)
    act_offsets = np.zeros(steps + 1, np.int64)
    act_index = np.empty(_MIN_CAPACITY, np.int32)
    act_u = np.empty(_MIN_CAPACITY, dtype)
    n_spikes = 0
    n_act = 0
    for t in range(steps):
        z_now = synaptic[t % (taps + 1)]
        z_old = synaptic[(t + 1) % (taps + 1)]  # z[t − L]; becomes z[t + 1]'s slot
        _scatter(z_now, live, t + taps, in_index, in_values, in_offsets[t], in_offsets[t + 1],
                 weight, stride, in_width, out_width, rows, cols)  # fmt: skip
        refractory = ring[t % ring_len]
        for pixel in range(pixels):
            if live[pixel] < t:
                continue
            lo, hi = pixel * cout, (pixel + 1) * cout
            a, d, z = state_a[lo:hi], state_d[lo:hi], z_now[lo:hi]
            old, ref = z_old[lo:hi], refractory[lo:hi]
            for o in range(cout):  # a = p·A[t−1], d = p·(D[t−1] + A[t−1]) from the last step
                dd = d[o] + tail_d * old[o]
                aa = a[o] + z[o] + tail_a * old[o]
                potential[o] = c_eps * dd + ref[o]
                d[o] = p_eps * (dd + aa)
                a[o] = p_eps * aa
                old[o] = 0.0
                ref[o] = 0.0
            if live[pixel] == t:  # every input has left the kernel: clear the rounding residue
                a[:] = 0.0
                d[:] = 0.0
            spikes = _grow(spikes, n_spikes + cout)
            if record:
                act_index = _grow(act_index, n_act + cout)
                act_u = _grow(act_u, n_act + cout)
            fired = False
            for o in range(cout):
                u = potential[o]
                if record and abs(u - theta) <= half_width:
                    act_index[n_act] = lo + o
                    act_u[n_act] = u
                    n_act += 1
                if u >= theta:
                    spikes[n_spikes] = lo + o
                    n_spikes += 1
                    fired = True
                    for k in range(1, ring_len):
                        ring[(t + k) % ring_len, lo + o] += ref_taps[k]
            if fired:
                live[pixel] = max(live[pixel], t + ring_len - 1)
        spike_offsets[t + 1] = n_spikes
        act_offsets[t + 1] = n_act
    return spike_offsets, spikes[:n_spikes], act_offsets, act_index[:n_act], act_u[:n_act]
