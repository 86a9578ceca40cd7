"""Event-driven forward pass of one SRM conv layer on the CPU (Numba), keeping what training needs.

The layer computes, step by step (Ts = 1 ms), exactly what :class:`spikegyro.snn.layers.SRMConv`
computes in batch: ``z[t] = conv(s_in[t])``, ``v[t] = Σ_k ε[k]·z[t − k]``, ``u[t] = v[t] +
Σ_k ν[k]·s_out[t − k]``, ``s_out[t] = u[t] ≥ θ``. It touches only what the input spikes reach:

- the convolution is a scatter: each input spike adds one weight column (C_out values) to each
  output pixel it reaches, in a ring of L + 1 synaptic maps ``z``; the spikes of one input pixel
  (adjacent in the lists) share their targets, and each target row is summed in vector registers
  over them (:func:`spikegyro.snn.simd.add_rows`);
- the PSP runs on the output side as the double pole ``(A, D)`` of the truncated alpha kernel
  ε[k] = c·k·pᵏ (k < L), with each input fed a second time L steps later with the tail weights,
  so that the response is exactly 0 from k = L on (the same recursion as
  :mod:`spikegyro.stream.stateful`)::

      A[t] = p·A[t−1] + z[t] − pᴸ·z[t−L]
      D[t] = p·D[t−1] + p·A[t−1] − L·pᴸ·z[t−L]          v[t] = c·D[t]

- the refractory kernel ν[k] = a·q^(k−1) (1 ≤ k < M) runs as a single pole R on the same
  neurons: ``R[t+1] = q·R[t] + a·s[t] − a·q^(M−1)·s[t+1−M]``, the last term read from the spike
  list of M − 1 steps ago, so that a spike costs two writes instead of M − 1;
- a pixel (all output channels at one position) is visited only while some input of the last
  L steps or some own spike of the last M−1 steps may still act on it; when its last input has
  expired its state is set to exactly 0. Adjacent live pixels are advanced as one run of
  contiguous neurons, in one branch-free loop that vectorises; thresholding is a second pass.

Besides the output spike lists, the pass records every (neuron, step) pair whose potential lies
within the surrogate's support, |u − θ| ≤ half-width, with u: the only pairs where the backward
pass (:mod:`spikegyro.snn.sparse_backward`) has a non-zero ρ(u). The half-width must be < θ (the
cut above exp(−1/tau_rho) of the peak), so that a neuron at rest (u = 0) is never such a pair.

Spike lists are CSR by step: ``offsets`` (T + 1,) int64 and flat neuron indices
``(y·W + x)·C + c`` (int32), channels-last like the weights. A layer's weights come in blocks of
output channels, ``(blocks, kh·kw, C_in, C_out / blocks)`` (:func:`channel_blocks`): the scatter
and the backward products run block by block, so that a block's weights stay in a core's L2
cache while every input of the step uses them. The
geometry of a layer is the int64 array ``[stride, in_width, out_width, kernel_w]`` with the
fan-out table of :func:`fanout` (the output pixels and taps each input pixel reaches).
"""

from __future__ import annotations

import numba
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from spikegyro.kernel_fit import fit_alpha_kernel, fit_exp_kernel
from spikegyro.snn.simd import add_rows

_MIN_CAPACITY = 1024


@numba.njit(cache=True, nogil=True)
def _grow(array: np.ndarray, size: int) -> np.ndarray:
    """``array`` if it holds at least ``size`` entries, else a copy at least twice as large."""
    if size <= array.size:
        return array
    bigger = np.empty(max(2 * array.size, size, _MIN_CAPACITY), array.dtype)
    bigger[: array.size] = array
    return bigger


@numba.njit(cache=True, nogil=True)
def fit(array: np.ndarray, size: int) -> np.ndarray:
    """``array`` if it holds at least ``size`` entries, else a new one (contents not kept) with
    a quarter to spare: a buffer kept from step to step settles at the largest size it met."""
    if size <= array.size:
        return array
    return np.empty(max(size + size // 4, _MIN_CAPACITY), array.dtype)


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
def coo_to_lists(
    indices: np.ndarray, values: np.ndarray, shape: tuple[int, int, int, int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input lists of every element of a sparse (N, C, H, W, T) tensor, from its COO indices
    (5, n) and values: (offsets (N, T + 1) into the shared index and value arrays, flat
    (y·W + x)·C + c int32, values); element b's lists are ``offsets[b] − offsets[b, 0]`` and the
    arrays' range ``offsets[b, 0]:offsets[b, T]``.

    Entries already in (element, step, flat index) order, as
    :func:`spikegyro.events.binning_torch.spike_tensor` with ``sparse`` stores them, are taken in
    one pass; any other order is sorted first, and entries at the same index are summed (the
    value of an uncoalesced sparse tensor). Zero values are kept (an input of 0 adds nothing).
    """
    elements, channels, height, width, steps = shape
    pixels = height * width * channels
    key = np.empty(values.size, np.int64)
    ordered = True
    for e in range(values.size):
        flat = (indices[2, e] * width + indices[3, e]) * channels + indices[1, e]
        key[e] = (indices[0, e] * steps + indices[4, e]) * pixels + flat
        ordered = ordered and (e == 0 or key[e] > key[e - 1])
    order = np.arange(values.size) if ordered else np.argsort(key, kind="mergesort")
    counts = np.zeros(elements * steps + 1, np.int64)
    index = np.empty(values.size, np.int32)
    out = np.empty(values.size, values.dtype)
    n = 0
    for j in range(values.size):
        e = order[j]
        if n and key[e] == key[order[j - 1]]:
            out[n - 1] += values[e]
            continue
        index[n], out[n] = key[e] % pixels, values[e]
        counts[key[e] // pixels + 1] += 1
        n += 1
    offsets = np.cumsum(counts)
    per_element = np.empty((elements, steps + 1), np.int64)
    for b in range(elements):
        per_element[b] = offsets[b * steps : (b + 1) * steps + 1]
    return per_element, index[:n], out[:n]


@numba.njit(cache=True, nogil=True)
def _reach(i: int, out_size: int, kernel: int, stride: int) -> tuple[int, int]:
    """The first and last output o with 0 <= i − o·stride < kernel, clipped to the map (an
    empty range when first > last)."""
    return max(0, (i - kernel + stride) // stride), min(out_size - 1, i // stride)


@numba.njit(cache=True, nogil=True)
def fanout(
    in_hw: tuple[int, int], out_hw: tuple[int, int], kernel: int, stride: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where each input pixel of a conv (square kernel, no padding) projects: CSR offsets
    (in_h·in_w + 1,) and pairs (2, n): the output pixel oy·out_w + ox and the kernel tap
    ky·kernel + kx that connects them, for every input pixel iy·in_w + ix in order."""
    counts = np.zeros(in_hw[0] * in_hw[1] + 1, np.int64)
    pairs = np.empty((2, in_hw[0] * in_hw[1] * kernel * kernel), np.int64)
    n = 0
    for iy in range(in_hw[0]):
        first_y, last_y = _reach(iy, out_hw[0], kernel, stride)
        for ix in range(in_hw[1]):
            first_x, last_x = _reach(ix, out_hw[1], kernel, stride)
            for oy in range(first_y, last_y + 1):
                for ox in range(first_x, last_x + 1):
                    pairs[0, n] = oy * out_hw[1] + ox
                    pairs[1, n] = (iy - oy * stride) * kernel + ix - ox * stride
                    n += 1
            counts[iy * in_hw[1] + ix + 1] = n
    return counts, pairs[:, :n].copy()


@numba.njit(cache=True, nogil=True)
def divisor(d: int) -> tuple[int, int]:
    """(m, s) with n // d == (n·m) >> s for every 0 <= n < 2³¹ and 1 <= d < 2³¹: a
    multiplication instead of a division (Granlund & Montgomery, PLDI 1994: m = ⌈2^s/d⌉,
    s = 31 + ⌈log₂ d⌉; m < 2³² + 1, so n·m fits in an int64). Neuron indices are int32, and a
    64-bit division per index cost a quarter of the time of feeding δ into the recursion."""
    bits = 0
    while (1 << bits) < d:
        bits += 1
    shift = 31 + bits
    return ((1 << shift) + d - 1) // d, shift


@numba.njit(cache=True, nogil=True)
def quotient(n: int, div: tuple[int, int]) -> int:
    """n // d for 0 <= n < 2³¹, with div = :func:`divisor` (d)."""
    return (np.int64(n) * div[0]) >> div[1]


@numba.njit(cache=True, nogil=True)
def pixel_group(
    index: np.ndarray, start: int, stop: int, cin: int, div: tuple[int, int]
) -> tuple[int, int]:
    """(input pixel of ``index[start]``, end of the run of entries at that pixel within
    ``start:stop``): entries of one pixel are adjacent in a list sorted by flat index;
    div = :func:`divisor` (cin)."""
    pixel = quotient(index[start], div)
    limit = (pixel + 1) * cin  # no division per entry
    end = start + 1
    while end < stop and index[end] < limit:
        end += 1
    return pixel, end


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
    fan: tuple[np.ndarray, np.ndarray],
    first_pixel: int,
) -> None:
    """Add ``value·W[tap, c, :]`` to the synaptic input map of every output pixel of the tile
    (``first_pixel`` on, as many as ``live`` holds) each input ``start:stop`` reaches (the
    convolution as a scatter from its non-zero inputs), one block of output channels after the
    other."""
    blocks, cin, width = weight.shape[0], weight.shape[2], weight.shape[3]
    cout = blocks * width
    div = divisor(cin)
    fan_offsets, fan_pairs = fan
    for block in range(blocks):
        i = start
        while i < stop:
            pixel_in, end = pixel_group(index, i, stop, cin, div)
            for k in range(fan_offsets[pixel_in], fan_offsets[pixel_in + 1]):
                pixel, tap = fan_pairs[0, k] - first_pixel, fan_pairs[1, k]
                if pixel < 0 or pixel >= live.size:
                    continue  # another tile's
                target = synaptic[pixel * cout + block * width : pixel * cout + (block + 1) * width]
                add_rows(target, weight[block, tap], index, values, (i, end), pixel_in * cin)
                live[pixel] = max(live[pixel], live_until)
            i = end


_BLOCK_BYTES = 160 * 1024  # of weights: a sixth of a core's L2 cache, beside ∂L/∂z and the state
_BLOCK_WIDTH = 64  # channels at least: narrower ones cost more in walking inputs than they save


def channel_blocks(weight: np.ndarray) -> np.ndarray:
    """(kh·kw, C_in, C_out) weights as (blocks, kh·kw, C_in, C_out / blocks), C-contiguous: the
    fewest blocks (a power of two) whose weights fit in _BLOCK_BYTES, each at least _BLOCK_WIDTH
    channels wide; one block where C_out does not divide so."""
    taps, cin, cout = weight.shape
    blocks = 1
    while (
        weight.nbytes // blocks > _BLOCK_BYTES and cout % (2 * blocks) == 0
        and cout // (2 * blocks) >= _BLOCK_WIDTH
    ):  # fmt: skip
        blocks *= 2
    split = weight.reshape(taps, cin, blocks, cout // blocks).transpose(2, 0, 1, 3)
    return np.ascontiguousarray(split)


def unblocked(blocked: np.ndarray) -> np.ndarray:
    """The (kh·kw, C_in, C_out) array of :func:`channel_blocks`' layout."""
    blocks, taps, cin, width = blocked.shape
    return np.ascontiguousarray(blocked.transpose(1, 2, 0, 3)).reshape(taps, cin, blocks * width)


def alpha_constants(
    kernel: np.ndarray, dtype: type, tau: float | None = None
) -> tuple[np.ndarray, int]:
    """([c, p, −pᴸ, −L·pᴸ] in ``dtype``, L) for the truncated PSP taps ε[k] = c·k·pᵏ, k < L.

    c = ε[1]/p and p = ε[2]/(2·ε[1]) from the first taps (computed in float64 from taps exact to
    the last bit of a double they give c = e/τs and p = exp(−1/τs) to rounding); the rest of the
    taps is checked against them. With ``tau`` = τs (ms), the constants of ∂v/∂τs follow:
    [c/τs², τs, −L²·pᴸ] (see :func:`_advance_tau`).
    """
    c, p = fit_alpha_kernel(kernel, "PSP kernel")
    size = np.asarray(kernel).size
    consts = [c, p, -(p**size), -size * p**size]
    if tau is not None:
        consts += [c / tau**2, tau, -(size**2) * p**size]
    return np.array(consts, dtype=dtype), size


def refractory_constants(
    kernel: np.ndarray, dtype: type, tau: float | None = None
) -> tuple[np.ndarray, int]:
    """([a, q, −a·q^(M−1)] in ``dtype``, M) for the refractory taps ν[k] = a·q^(k−1), 1 ≤ k < M
    (potential units; ν[0] = 0). With ``tau`` = τr (ms), the constants of ∂u/∂τr follow:
    [1/τr², −a·(M − 1)·q^(M−1)]."""
    a, q = fit_exp_kernel(kernel, "refractory kernel")
    size = np.asarray(kernel).size
    consts = [a, q, -a * q ** (size - 1)]
    if tau is not None:
        consts += [1.0 / tau**2, -a * (size - 1) * q ** (size - 1)]
    return np.array(consts, dtype=dtype), size


@numba.njit(cache=True, nogil=True)
def _advance_tau(
    state: np.ndarray,
    z_now: np.ndarray,
    z_old: np.ndarray,
    sensitivity: np.ndarray,
    n0: int,
    n1: int,
    alpha: np.ndarray,
    refractory: np.ndarray,
) -> None:
    """∂u[t]/∂τs and ∂u[t]/∂τr of the neurons ``n0:n1`` into ``sensitivity`` (2, neurons), and
    one step of the two recursions behind them (state rows 3 and 4); runs before
    :func:`_advance`, whose inputs it reads.

    With the moments M_j[t] = Σ_{k<L} kʲ·pᵏ·z[t − k] (A = M_0, D = M_1, v = c·D) and c = e/τs,
    p = exp(−1/τs): ∂v/∂τs = (c/τs²)·(M_2 − τs·M_1), and M_2 runs as a third pole,
    M_2[t] = p·(M_2 + 2·D + A)[t − 1] − L²·pᴸ·z[t − L] (exactly 0 from k = L on). With
    R = a·Σ_{1≤k<M} q^(k−1)·s[t − k] and R_1 = a·Σ_{1≤k<M} (k − 1)·q^(k−1)·s[t − k]:
    ∂R/∂τr = R_1/τr², R_1[t + 1] = q·(R_1 + R)[t] − a·(M − 1)·q^(M−1)·s[t + 1 − M] (that last
    term in :func:`_refract`). The spikes are held fixed (no gradient through the refractory
    feedback).
    """
    p_eps, tail_a, tail_d, gain_s, tau_s, tail_m = (
        alpha[1], alpha[2], alpha[3], alpha[4], alpha[5], alpha[6]
    )  # fmt: skip
    q_ref, gain_r = refractory[1], refractory[3]
    a, d, r = state[0, n0:n1], state[1, n0:n1], state[2, n0:n1]
    m, r1 = state[3, n0:n1], state[4, n0:n1]
    z, old = z_now[n0:n1], z_old[n0:n1]
    ds, dr = sensitivity[0, n0:n1], sensitivity[1, n0:n1]
    for o in range(n1 - n0):  # m = p·(M_2 + 2·D + A)[t−1], r1 = R_1[t]
        dd = d[o] + tail_d * old[o]
        aa = a[o] + z[o] + tail_a * old[o]
        mm = m[o] + tail_m * old[o]
        ds[o] = gain_s * (mm - tau_s * dd)
        dr[o] = gain_r * r1[o]
        m[o] = p_eps * (mm + 2.0 * dd + aa)
        r1[o] = q_ref * (r1[o] + r[o])


@numba.njit(cache=True, nogil=True)
def _record_tau(
    sensitivity: np.ndarray,
    act_index: np.ndarray,
    act_tau: np.ndarray,
    span: tuple[int, int],
    base: int,
) -> None:
    """Copy ∂u/∂τs and ∂u/∂τr of the active pairs ``span`` (neurons ``base`` + n) to
    act_tau[2j], act_tau[2j + 1]."""
    for j in range(span[0], span[1]):
        n = act_index[j] - base
        act_tau[2 * j] = sensitivity[0, n]
        act_tau[2 * j + 1] = sensitivity[1, n]


@numba.njit(cache=True, nogil=True)
def _advance(
    state: np.ndarray,
    z_now: np.ndarray,
    z_old: np.ndarray,
    potential: np.ndarray,
    n0: int,
    n1: int,
    alpha: np.ndarray,
    q_ref: float,
) -> None:
    """u[t] of the neurons ``n0:n1`` into ``potential`` and one step of their recursions; takes
    in z[t] and the tail of z[t − L] (its slot is cleared for z[t + 1]); the refractory pole
    decays by ``q_ref`` (this step's spikes are added after thresholding). Branch-free over
    contiguous memory, so it vectorises."""
    c_eps, p_eps, tail_a, tail_d = alpha[0], alpha[1], alpha[2], alpha[3]
    a, d, r, u = state[0, n0:n1], state[1, n0:n1], state[2, n0:n1], potential[n0:n1]
    z, old = z_now[n0:n1], z_old[n0:n1]
    for o in range(n1 - n0):  # a = p·A[t−1], d = p·(D[t−1] + A[t−1]), r = R[t] from the last step
        dd = d[o] + tail_d * old[o]
        aa = a[o] + z[o] + tail_a * old[o]
        u[o] = c_eps * dd + r[o]
        d[o] = p_eps * (dd + aa)
        a[o] = p_eps * aa
        r[o] = q_ref * r[o]
        old[o] = 0.0


_CHUNK = 64  # neurons per bit mask in _threshold


@numba.njit(cache=True, nogil=True)
def _threshold(
    potential: np.ndarray,
    n0: int,
    n1: int,
    theta: float,
    half_width: float,
    record: bool,
    lists: tuple[np.ndarray, np.ndarray, np.ndarray],
    counts: np.ndarray,
    base: int,
) -> None:
    """Append the neurons ``n0:n1`` (tile-local; ``base`` + n in the layer) with u ≥ θ to the
    spike list and, with ``record``, those with |u − θ| ≤ half-width (and their u) to the active
    lists; ``counts`` = [spikes, active]."""
    spikes, act_index, act_u = lists
    n_spikes, n_act = counts[0], counts[1]
    # The tests of 64 neurons become one bit mask each (vector compares), and only the set bits
    # are visited: a per-neuron branch taken at random 5-15 % of the time would be mispredicted
    # every few neurons, and a branch-free store per neuron costs more than the rare set bits.
    n = n0
    while n + _CHUNK <= n1:
        chunk = potential[n : n + _CHUNK]
        spiked = np.uint64(0)
        for k in range(_CHUNK):
            spiked |= np.uint64(chunk[k] >= theta) << np.uint64(k)
        n_spikes = _append_bits(spiked, base + n, spikes, n_spikes, chunk, act_u[:0])
        if record:
            near = np.uint64(0)
            for k in range(_CHUNK):
                near |= np.uint64(abs(chunk[k] - theta) <= half_width) << np.uint64(k)
            n_act = _append_bits(near, base + n, act_index, n_act, chunk, act_u)
        n += _CHUNK
    # The last < 64 neurons of the run, tested one by one: a mask of constant width lets the
    # loops above vectorise (one loop over both cases measured 2-7 % slower).
    for m in range(n, n1):
        u = potential[m]
        if u >= theta:
            spikes[n_spikes] = base + m
            n_spikes += 1
        if record and abs(u - theta) <= half_width:
            act_index[n_act] = base + m
            act_u[n_act] = u
            n_act += 1
    counts[0], counts[1] = n_spikes, n_act


@numba.njit(cache=True, nogil=True)
def _append_bits(
    bits: np.uint64,
    first: int,
    index: np.ndarray,
    count: int,
    values: np.ndarray,
    out_values: np.ndarray,
) -> int:
    """Append first + k to ``index`` (and values[k] to ``out_values`` unless it is empty) for
    every set bit k of ``bits``, from ``count`` on; returns the new count."""
    while bits:
        k = trailing_zeros(bits)
        index[count] = first + k
        if out_values.size:
            out_values[count] = values[k]
        count += 1
        bits &= bits - np.uint64(1)
    return count


@numba.njit(cache=True, nogil=True)
def _refract(
    spikes: np.ndarray,
    expiring: np.ndarray,
    state: np.ndarray,
    refractory: np.ndarray,
    live: np.ndarray,
    t: int,
    last: int,
    base: int,
) -> None:
    """R[t+1] of the neurons that spiked at step t (+a) and M − 1 steps earlier (−a·q^(M−1), the
    kernel's truncation; skipped where the pixel's state was just cleared); a new spike keeps its
    pixel live while its response lasts, to step ``last`` = t + M − 1. Neurons are numbered in
    the layer, ``base`` + the tile's own. refractory = [a, q, −a·q^(M−1)]
    (:func:`refractory_constants`), R in state row 2; with learned τ also R_1's truncation
    (refractory[4], row 4; :func:`_advance_tau`)."""
    pole = state[2]
    div = divisor(pole.size // live.size)
    learn = refractory.size > 3
    for n in expiring:
        if live[quotient(n - base, div)] > t:
            pole[n - base] += refractory[2]
            if learn:
                state[4, n - base] += refractory[4]
    for n in spikes:
        pixel = quotient(n - base, div)
        pole[n - base] += refractory[0]
        live[pixel] = max(live[pixel], last)


@numba.njit(cache=True, nogil=True)
def _update(
    state: np.ndarray,
    z_now: np.ndarray,
    z_old: np.ndarray,
    potential: tuple[np.ndarray, np.ndarray],
    live: np.ndarray,
    t: int,
    alpha: np.ndarray,
    refractory: np.ndarray,
    thresholds: tuple[float, float, bool],
    lists: Buffers,
    counts: np.ndarray,
    base: int,
) -> None:
    """Step ``t`` of every live pixel of the tile, in runs of adjacent ones; a pixel whose last
    input and own spike have expired has its state cleared (the rounding residue of the tail)
    and leaves. ``potential``: (u, sensitivities (2, neurons) to τ, used with learned τ: those
    of the active pairs go to lists[3])."""
    theta, half_width, record = thresholds
    cout = state.shape[1] // live.size
    learn = alpha.size > 4
    pixel = 0
    while pixel < live.size:
        if live[pixel] < t:
            pixel += 1
            continue
        end = pixel + 1
        while end < live.size and live[end] >= t:
            end += 1
        n0, n1 = pixel * cout, end * cout
        if learn:
            _advance_tau(state, z_now, z_old, potential[1], n0, n1, alpha, refractory)
        _advance(state, z_now, z_old, potential[0], n0, n1, alpha, refractory[1])
        first = counts[1]
        _threshold(potential[0], n0, n1, theta, half_width, record, lists[:3], counts, base)
        if learn and record:
            _record_tau(potential[1], lists[1], lists[3], (first, counts[1]), base)
        for q in range(pixel, end):
            if live[q] == t:  # every input has left the kernel
                state[:, q * cout : (q + 1) * cout] = 0.0
        pixel = end


_TILE_NEURONS = 8192  # × (L + 1 synaptic maps, 3 poles, u): ≈ 1 MB, a core's L2 cache

Buffers = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""Storage for (spike indices int32, active indices int32, active potentials, their derivatives
wrt τs and τr interleaved (learned τ only)) that a caller keeps between calls: the layer writes
into it and returns it, as a larger copy when it was too small."""

LayerLists = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""What a layer's pass gives: spike offsets (T + 1,), spike indices, active offsets (tiles,
T + 1), active indices, active potentials u, and with learned τ ∂u/∂τs, ∂u/∂τr of each active
pair j at [2j], [2j + 1] (else empty). The active pairs stay in the tiles' order: those of
step t are the ranges ``offsets[s, t]:offsets[s, t + 1]`` over the tiles s, each sorted by neuron,
the tiles in order of their neurons."""


@numba.njit(cache=True, nogil=True)
def layer_forward(
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray],
    weight: np.ndarray,
    geometry: np.ndarray,
    out_pixels: int,
    fan: tuple[np.ndarray, np.ndarray],
    alpha: np.ndarray,
    taps: int,
    refractory: tuple[np.ndarray, int],
    thresholds: tuple[float, float, bool],
    storage: tuple[np.ndarray, Buffers],
) -> tuple[LayerLists, tuple[np.ndarray, Buffers]]:
    """Run one layer over all steps; see the module docstring.

    Neurons are independent given their inputs, so the layer runs in tiles of whole output rows,
    each over all steps (its state stays in cache), one after the other. The tiles' spikes are
    merged step by step into one list (the next layer's input); their active pairs are left
    where the tiles wrote them, in ranges per tile and step (copying them, 8 bytes per pair,
    cost layer 1 a tenth of its pass on an idle machine, more while the memory was busy).

    Args:
        inputs: offsets, flat indices, values of the input lists (CSR by step; values multiply W).
        weight: (blocks, kh·kw, C_in, C_out / blocks) (:func:`channel_blocks`), the dtype of the
            computation (float32 or float64).
        geometry: [stride, input width, output width, kernel width] (px); out_pixels: output
            height × width; fan: :func:`fanout`.
        alpha: [c, p, −pᴸ, −L·pᴸ] of the PSP kernel ε[k] = c·k·pᵏ for k < L = ``taps``
            (steps), in the weight's dtype (:func:`alpha_constants`); followed by the
            constants of ∂u/∂τs when the pass also computes the derivatives wrt τ.
        refractory: ([a, q, −a·q^(M−1)] in the weight's dtype, M) of the refractory kernel
            ν[k] = a·q^(k−1), 1 ≤ k < M (potential units; :func:`refractory_constants`);
            with the constants of ∂u/∂τr when alpha has those of τs.
        thresholds: (θ, half-width of the surrogate's support, record): θ and the half-width as
            scalars of the weight's dtype, so that the comparisons are made in that precision as
            the batch path makes them; record: keep the pairs within the support (only a layer
            that back-propagates needs them).
        storage: (scratch, out): the tiles' spike lists go to scratch (int32), the merged spike
            list and the active pairs to the :data:`Buffers` out (u in the weight's dtype).
            Memory that a caller keeps between calls is written without the page faults of
            fresh memory, a large share of this pass.

    Returns:
        (:data:`LayerLists`, their indices and potentials views of out, valid until out is
        written again; (scratch, out) to keep).
    """
    out_width, cout = geometry[2], weight.shape[0] * weight.shape[3]
    tile_rows = max(1, _TILE_NEURONS // (out_width * cout))
    steps = inputs[0].size - 1
    scratch, out = storage
    lists = (scratch, out[1], out[2], out[3])
    start = np.zeros(2, np.int64)  # where the tile's lists begin: spikes, active
    tiles = []
    for first_row in range(0, out_pixels // out_width, tile_rows):
        last_row = min(first_row + tile_rows, out_pixels // out_width)
        offsets, lists = _tile_forward(inputs, weight, geometry, (first_row, last_row), fan,
                                       alpha, taps, refractory, thresholds, lists,
                                       start)  # fmt: skip
        tiles.append(offsets)
        start = offsets[:, -1].copy()
    spike_offsets, spikes = _merge(tiles, lists[0], out[0], steps)
    active = np.empty((len(tiles), steps + 1), np.int64)
    for s, tile in enumerate(tiles):
        active[s] = tile[1]
    n_spikes, n_active = spike_offsets[-1], start[1]
    n_tau = 2 * n_active if alpha.size > 4 and thresholds[2] else 0
    result = (spike_offsets, spikes[:n_spikes], active, lists[1][:n_active],
              lists[2][:n_active], lists[3][:n_tau])  # fmt: skip
    return result, (lists[0], (spikes, lists[1], lists[2], lists[3]))


@numba.njit(cache=True, nogil=True)
def _merge(
    tiles: list, scratch: np.ndarray, out: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """The spike list of the whole layer from the tiles' ranges of scratch (offsets (2, T + 1)
    each, spikes and active), step by step in tile order (so sorted by neuron), written into
    out: (offsets (T + 1,), out or a larger array)."""
    offsets = np.zeros(steps + 1, np.int64)
    for tile in tiles:
        offsets[1:] += tile[0, 1:] - tile[0, :-1]
    offsets = np.cumsum(offsets)
    out = fit(out, offsets[-1])
    fill = offsets[:-1].copy()
    for t in range(steps):
        for tile in tiles:
            lo, hi = tile[0, t], tile[0, t + 1]
            out[fill[t] : fill[t] + hi - lo] = scratch[lo:hi]
            fill[t] += hi - lo
    return offsets, out


@numba.njit(cache=True, nogil=True)
def _tile_forward(
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray],
    weight: np.ndarray,
    geometry: np.ndarray,
    tile: tuple[int, int],
    fan: tuple[np.ndarray, np.ndarray],
    alpha: np.ndarray,
    taps: int,
    refractory: tuple[np.ndarray, int],
    thresholds: tuple[float, float, bool],
    lists: Buffers,
    start: np.ndarray,
) -> tuple[np.ndarray, Buffers]:
    """:func:`layer_forward` for the output rows ``tile`` = (first, end): the same lists, for
    those rows' neurons only (numbered in the layer), appended to ``lists`` from ``start`` =
    [spikes, active] on. Returns their offsets (2, T + 1) into ``lists`` and ``lists`` (a larger
    copy when it filled up)."""
    in_offsets, in_index, in_values = inputs
    stride, in_width, out_width, kernel = geometry[0], geometry[1], geometry[2], geometry[3]
    steps = in_offsets.size - 1
    pixels = (tile[1] - tile[0]) * out_width
    cout = weight.shape[0] * weight.shape[3]
    neurons = pixels * cout
    dtype = weight.dtype
    # The inputs that reach these rows: a range of flat indices, found by bisection each step.
    row_size = in_width * weight.shape[2]
    bounds = (tile[0] * stride * row_size, ((tile[1] - 1) * stride + kernel) * row_size)
    ref_consts, ref_len = refractory
    learn = alpha.size > 4
    # p·A[t−1], p·(D[t−1] + A[t−1]), R[t] (and for learned τ the poles of _advance_tau)
    state = np.zeros((5 if learn else 3, neurons), dtype)
    # z[t] of the last L + 1 steps: z[t − L] leaves the PSP through the tail weights.
    synaptic = np.zeros((taps + 1, neurons), dtype)
    potential = (np.empty(neurons, dtype), np.empty((2, neurons if learn else 0), dtype))
    live = np.full(pixels, -1, np.int64)
    offsets = np.zeros((2, steps + 1), np.int64)  # spikes, active pairs
    offsets[:, 0] = start
    counts = start.copy()
    base = tile[0] * out_width * cout
    for t in range(steps):
        z_now = synaptic[t % (taps + 1)]
        step = in_index[in_offsets[t] : in_offsets[t + 1]]
        lo = in_offsets[t] + np.searchsorted(step, bounds[0])
        hi = in_offsets[t] + np.searchsorted(step, bounds[1])
        _scatter(z_now, live, t + taps, in_index, in_values, lo, hi, weight, fan,
                 tile[0] * out_width)  # fmt: skip
        # Room for every neuron of the step, so that the passes below need not check.
        active_room = counts[1] + neurons if thresholds[2] else 0
        lists = (_grow(lists[0], counts[0] + neurons), _grow(lists[1], active_room),
                 _grow(lists[2], active_room),
                 _grow(lists[3], 2 * active_room if learn else 0))  # fmt: skip
        first = counts[0]
        _update(state, z_now, synaptic[(t + 1) % (taps + 1)], potential, live, t, alpha,
                ref_consts, thresholds, lists, counts, base)  # fmt: skip
        old = t + 1 - ref_len  # the spikes of step t + 1 − M leave the refractory kernel
        expiring = lists[0][offsets[0, old] : offsets[0, old + 1]] if old >= 0 else lists[0][:0]
        _refract(lists[0][first : counts[0]], expiring, state, ref_consts, live, t,
                 t + ref_len - 1, base)  # fmt: skip
        offsets[:, t + 1] = counts
    return offsets, lists
