"""Network input representations of an event window.

Every function takes the event coordinates as NumPy arrays or torch tensors (on any device) and
returns the same kind it was given. Internally the work is done in torch, on the device of the
input, with scatter-adds: no Python loop over events.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch

from spikegyro.errors import InputError

ArrayLike = Any  # np.ndarray | torch.Tensor


def _as_tensor(a: ArrayLike) -> torch.Tensor:
    if isinstance(a, torch.Tensor):
        return a
    a = np.ascontiguousarray(a)
    # a one-element reversed view counts as contiguous but keeps its negative stride
    return torch.from_numpy(a.copy() if any(s < 0 for s in a.strides) else a)


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


@numba.njit(cache=True, nogil=True)
def _voxel_scatter(
    x: np.ndarray,
    y: np.ndarray,
    t: np.ndarray,
    p: np.ndarray,
    out: np.ndarray,
    t_start_us: int,
    span_us: int,
    num_bins: int,
) -> None:
    """Add each event's signed polarity to ``out`` (grids, num_bins, H, W), zeroed: grid
    ``(t - t_start) // span``, bins by :func:`voxel_grid`'s formula, every low bin's share
    added first and every high bin's after, in event order, as ``index_add_`` adds them."""
    grids = out.shape[0]
    for half in range(2):
        for e in range(t.size):
            local = t[e] - t_start_us
            grid = local // span_us
            if grid < 0 or grid >= grids:
                continue
            ts = (num_bins - 1) * np.float64(local - grid * span_us) / span_us
            ts = min(max(ts, 0.0), num_bins - 1.0)
            lo = int(np.floor(ts))
            frac = np.float32(ts - lo)
            polarity = np.float32(p[e]) * np.float32(2) - np.float32(1)
            if half == 0:
                out[grid, lo, y[e], x[e]] += polarity * (np.float32(1) - frac)
            else:
                out[grid, min(lo + 1, num_bins - 1), y[e], x[e]] += polarity * frac


def voxel_grids(
    x: np.ndarray,
    y: np.ndarray,
    t: np.ndarray,
    p: np.ndarray,
    *,
    height: int,
    width: int,
    num_bins: int,
    t_start_us: int,
    span_us: int,
    count: int,
) -> np.ndarray:
    """:func:`voxel_grid` of ``count`` consecutive spans of ``span_us`` µs from ``t_start_us``
    (each span its own [t0, tN]), in one pass over NumPy events: (count, num_bins, height,
    width) float32, equal to stacking :func:`voxel_grid` of each span's events. Events outside
    the spans are left out."""
    out = np.zeros((count, num_bins, height, width), np.float32)
    if len(t):
        _voxel_scatter(np.asarray(x), np.asarray(y), np.asarray(t), np.asarray(p), out,
                       int(t_start_us), int(span_us), int(num_bins))  # fmt: skip
    return out


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


LOG_POLAR_R_MIN = 2.0
"""Default inner radius (px) of the log-polar grid: events closer to the centre are left out of
it (their angle is not resolved by the pixel grid); the Cartesian channels still hold them."""


def log_polar_coordinates(
    x: ArrayLike,
    y: ArrayLike,
    *,
    height: int,
    width: int,
    centre: tuple[float, float],
    r_min: float = LOG_POLAR_R_MIN,
) -> tuple[ArrayLike, ArrayLike, ArrayLike]:
    """Events' cells on a log-polar grid of the same ``height`` x ``width`` around ``centre``.

    Column = angle: ``col = floor(width * a / 2π)`` with ``a = atan2(y - cy, x - cx)`` taken in
    [0, 2π) (radians, image axes: x right, y down). Row = log radius:
    ``row = floor(height * ln(r / r_min) / ln(r_max / r_min))``, r the distance to the centre
    in pixels and r_max the distance to the farthest image corner, so rows run from the centre
    (row 0) outwards. A rotation of the image by φ about the centre (a roll, when ``centre`` is
    the principal point and fx = fy) moves every event ``width * φ / 2π`` columns along the
    rows: a horizontal translation, the same at every radius. A radial scaling by s moves it
    ``height * ln(s) / ln(r_max / r_min)`` rows.

    Args:
        x, y: pixel coordinates (integer or real; pixel centres at integers).
        height, width: size of the image and of the log-polar grid, pixels and cells.
        centre: (cx, cy), pixels: usually the principal point.
        r_min: inner radius, pixels; events nearer the centre get ``keep = False``.

    Returns:
        (col, row, keep): int64 cells (clamped into the grid) and the boolean mask of events
        at ``r >= r_min``, of the kind (NumPy or torch) that ``x`` is.
    """
    if height < 1 or width < 1 or r_min <= 0:
        raise InputError(f"log-polar grid {width}x{height} with r_min {r_min}: need sizes >= 1 "
                         "and r_min > 0.")  # fmt: skip
    cx, cy = float(centre[0]), float(centre[1])
    dx = _as_tensor(x).to(torch.float64) - cx
    dy = _as_tensor(y).to(torch.float64) - cy
    corners = [(a - cx) ** 2 + (b - cy) ** 2 for a in (0, width - 1) for b in (0, height - 1)]
    r_max = max(max(corners) ** 0.5, r_min * 1.01)
    radius = torch.hypot(dx, dy)
    angle = torch.remainder(torch.atan2(dy, dx), 2 * torch.pi)
    col = torch.floor(angle * (width / (2 * torch.pi))).long().clamp(0, width - 1)
    log_r = torch.log(radius.clamp(min=r_min) / r_min) / np.log(r_max / r_min)
    row = torch.floor(log_r * height).long().clamp(0, height - 1)
    keep = radius >= r_min
    return _like(col, x), _like(row, x), _like(keep, x)


def log_polar_pixel_map(
    height: int, width: int, centre: tuple[float, float], r_min: float = LOG_POLAR_R_MIN
) -> torch.Tensor:
    """Flat log-polar cell (``row * width + col``) of every pixel, (height * width,) int64 in
    row-major pixel order; pixels inside ``r_min`` map to ``height * width`` (no cell)."""
    ys, xs = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    col, row, keep = log_polar_coordinates(
        xs.reshape(-1), ys.reshape(-1), height=height, width=width, centre=centre, r_min=r_min
    )
    return torch.where(keep, row * width + col, torch.full_like(col, height * width))


def log_polar_spikes(
    spikes: torch.Tensor, pixel_map: torch.Tensor, *, spatial_dim: int
) -> torch.Tensor:
    """Re-map binary spike maps to the log-polar grid of :func:`log_polar_pixel_map`.

    ``spikes`` has the image's height and width at ``spatial_dim`` and ``spatial_dim + 1``; a
    cell is 1 when any pixel mapped to it is (a max, so the result equals binning the
    log-polar coordinates of the events themselves with :func:`spike_tensor`). Same shape and
    dtype as ``spikes``.
    """
    shape = spikes.shape
    height, width = shape[spatial_dim], shape[spatial_dim + 1]
    if pixel_map.numel() != height * width:
        raise InputError(f"log-polar map of {pixel_map.numel()} pixels for a {width}x{height} "
                         "input; build the map for the input's size.")  # fmt: skip
    flat = spikes.reshape(*shape[:spatial_dim], height * width, *shape[spatial_dim + 2 :])
    index_shape = [1] * flat.dim()
    index_shape[spatial_dim] = height * width
    index = pixel_map.to(spikes.device).view(index_shape).expand_as(flat)
    out_shape = list(flat.shape)
    out_shape[spatial_dim] = height * width + 1  # the last cell collects the dropped centre
    out = torch.zeros(out_shape, dtype=spikes.dtype, device=spikes.device)
    out.scatter_reduce_(spatial_dim, index, flat, reduce="amax")
    return out.narrow(spatial_dim, 0, height * width).reshape(shape)


def check_window(num_events: int, source: str, t_start_us: int, t_end_us: int) -> None:
    """Raise a clear :class:`InputError` for an empty event window."""
    if num_events == 0:
        raise InputError(
            f"{source}: no events in the window [{t_start_us}, {t_end_us}) us; choose another "
            "window (--start/--end) or check the file's time base."
        )
