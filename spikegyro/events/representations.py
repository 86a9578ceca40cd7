"""Network input representations of an event window.

Every function takes the event coordinates as NumPy arrays or torch tensors (on any device) and
returns the same kind it was given. Internally the work is done in torch, on the device of the
input, with scatter-adds: no Python loop over events.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from spikegyro.errors import InputError

ArrayLike = Any  # np.ndarray | torch.Tensor


def _as_tensor(a: ArrayLike) -> torch.Tensor:
    return a if isinstance(a, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(a))


def _like(result: torch.Tensor, template: ArrayLike) -> ArrayLike:
    return result if isinstance(template, torch.Tensor) else result.cpu().numpy()


def spike_tensor(
    x: ArrayLike,
    y: ArrayLike,
    t: ArrayLike,
    p: ArrayLike,
    *,
    height: int,
    width: int,
    t_start_us: int,
    num_bins: int,
    bin_us: int = 1000,
    count: bool = False,
) -> ArrayLike:
    """Bin events into a (2, height, width, num_bins) spike tensor.

    Bin k covers ``[t_start_us + k*bin_us, t_start_us + (k+1)*bin_us)`` (microseconds); channel
    0 holds OFF events and channel 1 ON events. Events outside the covered time span are dropped.

    Args:
        x, y: pixel coordinates (0-based).
        t: timestamps, microseconds.
        p: polarity, 0 = OFF, 1 = ON.
        count: if False (the official code's input), a bin is 1 when at least one event fell in
            it; if True, it holds the number of events.

    Returns:
        float32 tensor/array of shape (2, height, width, num_bins).
    """
    tt = _as_tensor(t).to(torch.int64)
    k = torch.div(tt - int(t_start_us), int(bin_us), rounding_mode="floor")
    keep = (k >= 0) & (k < num_bins)
    xs, ys = _as_tensor(x).long()[keep], _as_tensor(y).long()[keep]
    ps, ks = _as_tensor(p).long()[keep], k[keep]
    flat = ((ps * height + ys) * width + xs) * num_bins + ks
    out = torch.zeros(2 * height * width * num_bins, dtype=torch.float32, device=tt.device)
    if count:
        out.index_add_(0, flat, torch.ones_like(flat, dtype=torch.float32))
    else:
        out[flat] = 1.0
    return _like(out.view(2, height, width, num_bins), t)


def voxel_grid(
    x: ArrayLike,
    y: ArrayLike,
    t: ArrayLike,
    p: ArrayLike,
    *,
    height: int,
    width: int,
    num_bins: int,
    t_start_us: int | None = None,
    t_end_us: int | None = None,
) -> ArrayLike:
    """Voxel grid of Zhu et al. (2019): (num_bins, height, width), float32.

    Each event's normalized time is t* = (B - 1) (t - t0) / (tN - t0), with t0, tN the window's
    start and end (by default the first and last event). The event adds its signed polarity
    (+1 ON, -1 OFF) to bin floor(t*) with weight 1 - frac(t*) and to bin floor(t*) + 1 with
    weight frac(t*); an event exactly at tN puts all its weight in bin B - 1.
    """
    tt = _as_tensor(t).to(torch.float64)
    out = torch.zeros(num_bins * height * width, dtype=torch.float32, device=tt.device)
    if tt.numel() == 0:
        return _like(out.view(num_bins, height, width), t)
    t0 = float(tt[0]) if t_start_us is None else float(t_start_us)
    tn = float(tt[-1]) if t_end_us is None else float(t_end_us)
    span = max(tn - t0, 1e-9)
    ts = ((num_bins - 1) * (tt - t0) / span).clamp(0, num_bins - 1)
    lo = ts.floor()
    frac = (ts - lo).to(torch.float32)
    lo = lo.long()
    polarity = _as_tensor(p).to(torch.float32) * 2 - 1
    pix = _as_tensor(y).long() * width + _as_tensor(x).long()
    out.index_add_(0, lo * height * width + pix, polarity * (1 - frac))
    hi = (lo + 1).clamp(max=num_bins - 1)
    out.index_add_(0, hi * height * width + pix, polarity * frac)
    return _like(out.view(num_bins, height, width), t)


def accumulated_frames(
    x: ArrayLike,
    y: ArrayLike,
    p: ArrayLike,
    *,
    height: int,
    width: int,
    percentile: float = 99.0,
) -> ArrayLike:
    """Two-channel event frames of Maqueda et al. (2018): (2, height, width), float32 in [0, 1].

    Channel 0 counts OFF events and channel 1 ON events per pixel. Counts are clipped at the
    ``percentile`` of all non-zero counts (both channels together) and divided by that value,
    so isolated hot pixels do not squash the rest of the image.
    """
    xs = _as_tensor(x).long()
    flat = (_as_tensor(p).long() * height + _as_tensor(y).long()) * width + xs
    counts = torch.zeros(2 * height * width, dtype=torch.float32, device=xs.device)
    counts.index_add_(0, flat, torch.ones_like(flat, dtype=torch.float32))
    nonzero = counts[counts > 0]
    if nonzero.numel():
        scale = torch.quantile(nonzero, percentile / 100.0)
        counts = counts.clamp(max=float(scale)) / scale
    return _like(counts.view(2, height, width), x)


def check_window(num_events: int, source: str, t_start_us: int, t_end_us: int) -> None:
    """Raise a clear :class:`InputError` for an empty event window."""
    if num_events == 0:
        raise InputError(
            f"{source}: no events in the window [{t_start_us}, {t_end_us}) us; choose another "
            "window (--start/--end) or check the file's time base."
        )
