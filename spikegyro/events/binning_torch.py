"""Batched input representations of many event windows at once, built where the events are.

The functions of :mod:`spikegyro.events.representations`, with the same names and the same
arithmetic, for a *batch*: the events of ``num_windows`` windows concatenated into flat tensors
plus ``window``, the index (0 … num_windows − 1) of the window each event belongs to. They run on
the device of the events (scatter/index_put, no Python loop over events or windows, no
host-device synchronisation), so a training step can ship ~1 MB of events per window to the GPU
instead of a 35 MB dense tensor and bin them there. Each window's slice of the result equals what
the one-window function returns for that window's events: bit for bit on the CPU; on a GPU the
float sums of the voxel grid may differ in their last bit (atomic adds are unordered).
:func:`spike_tensor` with ``sparse`` bins spikes on the CPU into a sparse tensor for the
event-driven engine, which never needs the dense one.

Times are microseconds, relative to whatever origin ``t_start_us``/``t_end_us`` use (the
training data path sends times relative to each window's start, so int32 suffices).
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from numba.cpython.unsafe.numbers import trailing_zeros


def spike_tensor(
    x: torch.Tensor,
    y: torch.Tensor,
    t: torch.Tensor,
    p: torch.Tensor,
    window: torch.Tensor,
    *,
    num_windows: int,
    height: int,
    width: int,
    num_bins: int,
    t_start_us: int = 0,
    bin_us: int = 1000,
    count: bool = False,
    sparse: bool = False,
) -> torch.Tensor:
    """Bin the events of a batch into (num_windows, 2, height, width, num_bins) spike tensors.

    Same bins and values as :func:`spikegyro.events.representations.spike_tensor` for each
    window: bin k covers ``[t_start_us + k*bin_us, t_start_us + (k+1)*bin_us)`` µs, channel 0 =
    OFF, 1 = ON, events outside the bins are dropped; 0/1 or (``count``) event counts.

    Returns:
        float32 tensor on the events' device, a (N, 2, H, W, T) view of time-major,
        channels-last storage (T, N, H, W, 2): the layout SNN-6's layers work in, so the first
        layer reads it without a copy. With ``sparse``, a sparse COO tensor instead (binned on
        the CPU with Numba; no dense tensor, which takes 35 MB per 100 ms window at 240x180),
        its entries stored in the order the event-driven engine reads them (window, step,
        pixel, channel). It is not marked coalesced, since that order is not the lexicographic
        order of its (N, C, H, W, T) indices; ``coalesce()`` sorts it.
    """
    if sparse:
        arrays = [a.detach().cpu().numpy() for a in (x, y, t, p, window)]
        shape = (num_windows, 2, height, width, num_bins)
        indices, values = _spike_entries(*arrays, shape, int(t_start_us), int(bin_us), count)
        return torch.sparse_coo_tensor(
            torch.from_numpy(indices),
            torch.from_numpy(values),
            shape,
            is_coalesced=False,
            check_invariants=False,  # built valid below; the check costs a pass over the entries
        ).to(t.device)
    k = torch.div(t.long() - int(t_start_us), int(bin_us), rounding_mode="floor")
    keep = (k >= 0) & (k < num_bins)
    size = num_bins * num_windows * height * width * 2
    flat = (((k * num_windows + window.long()) * height + y.long()) * width + x.long()) * 2
    flat = flat + p.long()
    # Dropped events go to one spare slot past the end: no boolean indexing, no device sync.
    flat = torch.where(keep, flat, size)
    out = torch.zeros(size + 1, dtype=torch.float32, device=t.device)
    if count:
        out.index_add_(0, flat, keep.to(torch.float32))
    else:
        out.index_fill_(0, flat, 1.0)
    dense = out[:size].view(num_bins, num_windows, height, width, 2)
    return dense.permute(1, 4, 2, 3, 0)


@numba.njit(cache=True, nogil=True)
def _spike_entries(
    x: np.ndarray,
    y: np.ndarray,
    t: np.ndarray,
    p: np.ndarray,
    window: np.ndarray,
    shape: tuple[int, int, int, int, int],
    t_start_us: int,
    bin_us: int,
    count: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Indices (5, n) (window, channel, y, x, step) and float32 values of the non-zero bins, in
    (window, step, pixel, channel) order: events bucketed by (window, step), then each bucket's
    distinct neurons taken in order from a bit set (no sort)."""
    windows, channels, height, width, bins = shape
    neurons = height * width * channels
    bucket = np.full(t.size, -1, np.int64)
    starts = np.zeros(windows * bins + 1, np.int64)
    for e in range(t.size):
        k = (np.int64(t[e]) - t_start_us) // bin_us
        if 0 <= k < bins:
            bucket[e] = window[e] * bins + k
            starts[bucket[e] + 1] += 1
    starts = np.cumsum(starts)
    fill = starts[:-1].copy()
    flat = np.empty(starts[-1], np.int64)
    for e in range(t.size):
        if bucket[e] >= 0:
            flat[fill[bucket[e]]] = (np.int64(y[e]) * width + x[e]) * channels + p[e]
            fill[bucket[e]] += 1
    # Each neuron's (channel, y, x), looked up instead of divided out per entry.
    neuron_of = np.arange(neurons)
    coords = (neuron_of % channels, neuron_of // channels // width, neuron_of // channels % width)
    bits = np.zeros((neurons + 63) // 64, np.uint64)
    distinct = 0  # counted first, so that the entries need no copy to trim them
    for b in range(windows * bins):
        for j in range(starts[b], starts[b + 1]):
            bits[flat[j] >> 6] |= np.uint64(1) << np.uint64(flat[j] & 63)
        for j in range(starts[b], starts[b + 1]):
            bit = np.uint64(1) << np.uint64(flat[j] & 63)
            distinct += (bits[flat[j] >> 6] & bit) != 0
            bits[flat[j] >> 6] &= ~bit
    hits = np.zeros(neurons, np.float32)
    indices = np.empty((5, distinct), np.int64)
    values = np.empty(distinct, np.float32)
    n = 0
    for b in range(windows * bins):
        for j in range(starts[b], starts[b + 1]):
            bits[flat[j] >> 6] |= np.uint64(1) << np.uint64(flat[j] & 63)
            hits[flat[j]] += 1.0
        for word in range(bits.size):
            while bits[word]:
                neuron = word * 64 + trailing_zeros(bits[word])
                bits[word] &= bits[word] - np.uint64(1)
                indices[0, n], indices[4, n] = b // bins, b % bins
                indices[1, n], indices[2, n], indices[3, n] = (
                    coords[0][neuron],
                    coords[1][neuron],
                    coords[2][neuron],
                )
                values[n] = hits[neuron] if count else 1.0
                hits[neuron] = 0.0
                n += 1
    return indices, values


def voxel_grid(
    x: torch.Tensor,
    y: torch.Tensor,
    t: torch.Tensor,
    p: torch.Tensor,
    window: torch.Tensor,
    *,
    num_windows: int,
    height: int,
    width: int,
    num_bins: int,
    t_start_us: int,
    t_end_us: int,
) -> torch.Tensor:
    """Voxel grids of Zhu et al. (2019) of every window: (num_windows, num_bins, height, width).

    The formula of :func:`spikegyro.events.representations.voxel_grid` with an explicit time
    span ``[t_start_us, t_end_us]`` (µs) shared by all windows: t* = (B − 1)(t − t0)/(tN − t0),
    clamped to [0, B − 1]; each event adds its signed polarity to bins floor(t*) and
    floor(t*) + 1 with linear weights. float32.
    """
    hw = height * width
    out = torch.zeros(num_windows * num_bins * hw, dtype=torch.float32, device=t.device)
    tt = t.to(torch.float64)
    span = max(float(t_end_us) - float(t_start_us), 1e-9)
    ts = ((num_bins - 1) * (tt - float(t_start_us)) / span).clamp(0, num_bins - 1)
    lo = ts.floor()
    frac = (ts - lo).to(torch.float32)
    lo = lo.long()
    polarity = p.to(torch.float32) * 2 - 1
    base = window.long() * num_bins
    pix = y.long() * width + x.long()
    out.index_add_(0, (base + lo) * hw + pix, polarity * (1 - frac))
    hi = (lo + 1).clamp(max=num_bins - 1)
    out.index_add_(0, (base + hi) * hw + pix, polarity * frac)
    return out.view(num_windows, num_bins, height, width)


def accumulated_frames(
    x: torch.Tensor,
    y: torch.Tensor,
    p: torch.Tensor,
    window: torch.Tensor,
    *,
    num_windows: int,
    height: int,
    width: int,
    percentile: float = 99.0,
) -> torch.Tensor:
    """Two-channel event frames of every window: (num_windows, 2, height, width) in [0, 1].

    As :func:`spikegyro.events.representations.accumulated_frames` per window: OFF and ON counts
    per pixel, clipped at the ``percentile`` of the window's non-zero counts and divided by it.
    The percentile is torch.quantile's linear interpolation, computed for all windows at once
    on the sorted counts (the non-zero ones are the last n of each sorted row).
    """
    plane = 2 * height * width
    flat = window.long() * plane + (p.long() * height + y.long()) * width + x.long()
    counts = torch.zeros(num_windows * plane, dtype=torch.float32, device=x.device)
    counts.index_add_(0, flat, torch.ones_like(flat, dtype=torch.float32))
    counts = counts.view(num_windows, plane)
    nonzero = (counts > 0).sum(dim=1)
    ordered = counts.sort(dim=1).values
    q = torch.tensor(percentile / 100.0, dtype=torch.float32, device=x.device)
    rank = q * (nonzero - 1).clamp(min=0).to(torch.float32)
    below = rank.long()
    above = rank.ceil().long()
    first = plane - nonzero
    low = ordered.gather(1, (first + below).clamp(max=plane - 1)[:, None])
    high = ordered.gather(1, (first + above).clamp(max=plane - 1)[:, None])
    scale = torch.lerp(low, high, (rank - below.to(torch.float32))[:, None])
    scaled = counts.clamp(max=scale) / scale
    frames = torch.where(nonzero[:, None] > 0, scaled, counts)
    return frames.view(num_windows, 2, height, width)
