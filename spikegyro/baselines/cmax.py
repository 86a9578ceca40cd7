"""Contrast maximization (Gallego and Scaramuzza, RA-L 2017): angular velocity without learning.

For a window of events and a candidate angular velocity ω (rad/s, camera frame: x right, y down,
z forward), every event is rotated to a reference time ``t_ref`` in the middle of the window,
the warped events are accumulated into an image of warped events (IWE) by bilinear voting and
smoothed with a Gaussian, and the ω that maximizes the image variance is the estimate: only the
true rotation brings the events of each edge back onto that edge.

Warp sign. With ``R_wc(t)`` camera-to-world and ``dR/dt = R [ω]x`` (ω as a camera-mounted gyro
reads it), a static world direction ``b_w`` seen in the camera frame is ``b(t) = R(t)^T b_w``, so
``db/dt = -[ω]x b`` and, for constant ω, ``b(t_ref) = exp(-[ω]x (t_ref - t)) b(t)``.

Search. A batched grid over ω, scored on a downscaled IWE of a subsample of the events smoothed
as wide as the grid spacing, finds the right basin even at fast motions. Its best points (plus
the warm start, e.g. the previous window's estimate) are refined with L-BFGS (autograd)
coarse-to-fine over an image pyramid on that subsample, compared by their contrast at full
resolution, and the winner is refined there on all events (up to ``max_events``).

Streams. ω is estimated every ``stride_ms`` from the window of events ending there and held
until the next estimate, so the prediction for a 1 ms step uses only past events (it lags the
truth by about half a window).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from spikegyro.events.calib import DEFAULT_FOCAL_PX, DEFAULT_WIDTH, PinholeCamera
from spikegyro.events.core import EventArray

Progress = Callable[[int, int], Any]


class Intrinsics(Protocol):
    """Pinhole intrinsics in pixels (``PinholeCamera``, ``spikegyro.sim.Camera`` satisfy it)."""

    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class CMaxConfig:
    """Settings of the contrast-maximization estimator.

    Attributes:
        window_ms: each window spans at least this long, ms.
        window_events: ... and is extended into the past until it holds this many events (0: a
            fixed-duration window), but never beyond ``max_window_ms``.
        max_window_ms: the longest window, ms.
        stride_ms: a stream is estimated every ``stride_ms`` ms, each estimate held until the
            next one.
        max_events: windows with more events are randomly subsampled to this many (speed).
        min_events: windows with fewer events keep the previous estimate (zero at the start).
        levels: image downscale factors of the pyramid, coarse to fine (the last is usually 1).
        sigma_px: Gaussian smoothing of the IWE, pixels of each pyramid level.
        iterations: L-BFGS iterations per pyramid level.
        grid_points: grid points per axis of the coarse search (odd, so 0 is on the grid).
        grid_max_dps: the grid spans ``[-grid_max_dps, grid_max_dps]`` deg/s on each axis.
        grid_events: events (random subsample) scored by the grid.
        starts: how many of the best grid points are refined (besides the warm start).
        grid_every: in a stream, search the grid again every ``grid_every`` estimates so a
            lost track recovers (0: never); it is always searched until the window is full.
        search_events: events (random subsample) used to refine and compare the starts.
        use_polarity: accumulate signed polarities instead of event counts.
        seed: seed of the event subsampling.
    """

    window_ms: float = 30.0
    window_events: int = 0
    max_window_ms: float = 50.0
    stride_ms: int = 5
    max_events: int = 8000
    min_events: int = 100
    levels: tuple[int, ...] = (4, 2, 1)
    sigma_px: float = 0.7
    iterations: int = 6
    grid_points: int = 9
    grid_max_dps: float = 1000.0
    grid_events: int = 2000
    starts: int = 2
    grid_every: int = 10
    search_events: int = 3000
    use_polarity: bool = False
    seed: int = 0


@dataclass(frozen=True)
class _Problem:
    """One window ready for warping (float32 tensors)."""

    bearings: torch.Tensor  # (N, 3) rays (x, y, 1) of the events in the camera frame
    dt_s: torch.Tensor  # (N,) t_ref - t, seconds
    weights: torch.Tensor  # (N,) 1, or the signed polarity
    camera: Intrinsics
    width: int
    height: int

    def __len__(self) -> int:
        return int(self.dt_s.shape[0])

    def subset(self, n: int, rng: np.random.Generator) -> _Problem:
        """At most ``n`` events drawn at random (the same problem when it has no more)."""
        if len(self) <= n:
            return self
        keep = torch.from_numpy(np.sort(rng.choice(len(self), n, replace=False)))
        return _Problem(
            self.bearings[keep],
            self.dt_s[keep],
            self.weights[keep],
            self.camera,
            self.width,
            self.height,
        )

    @property
    def px_per_rad_s(self) -> float:
        """Image displacement (px) that 1 rad/s causes at the window's ends: ω's natural scale."""
        half_span = float(self.dt_s.abs().max()) if len(self) else 0.0
        return max(half_span, 1e-4) * float(self.camera.fx)


def default_camera(width: int, height: int) -> PinholeCamera:
    """The simulator's pinhole (f = 200 px at 240 px wide) on a ``width`` x ``height`` sensor."""
    f = DEFAULT_FOCAL_PX * width / DEFAULT_WIDTH
    return PinholeCamera(width, height, f, f, width / 2.0, height / 2.0)


def camera_from_attrs(attrs: dict[str, Any], width: int, height: int) -> PinholeCamera:
    """Intrinsics from a sequence file's attributes (fx, fy, cx, cy), else the defaults."""
    base = default_camera(width, height)
    return PinholeCamera(
        width,
        height,
        float(attrs.get("fx", base.fx)),
        float(attrs.get("fy", attrs.get("fx", base.fy))),
        float(attrs.get("cx", base.cx)),
        float(attrs.get("cy", base.cy)),
    )


def rotate_bearings(
    bearings: torch.Tensor, omega: torch.Tensor, dt_s: torch.Tensor
) -> torch.Tensor:
    """Rotate camera-frame rays by ``exp(-[ω]x dt)`` (Rodrigues): where they point ``dt`` later.

    Args:
        bearings: (N, 3) rays in the camera frame.
        omega: (3,) or (M, 3) angular velocity, rad/s.
        dt_s: (N,) time to move each ray forward, seconds.

    Returns:
        (N, 3) or (M, N, 3) rotated rays.
    """
    # exp(-[ω]x dt) b = b - sin(n dt)/n (ω x b) + (1 - cos(n dt))/n² ω x (ω x b), n = |ω|, with
    # ω x (ω x b) = ω (ω·b) - b n². Written per component: elementwise ops on (M, N) tensors are
    # much faster than batched 3x3 matrix products. The floor under n keeps the expression and
    # its gradient smooth at ω = 0.
    wx, wy, wz = (w[..., None] for w in omega.unbind(-1))  # (..., 1) each
    bx, by, bz = bearings.unbind(-1)  # (N,) each
    n2 = wx * wx + wy * wy + wz * wz + 1e-12
    n = torch.sqrt(n2)
    angle = n * dt_s
    sin_term = torch.sin(angle) / n
    cos_term = 2.0 * torch.sin(0.5 * angle) ** 2 / n2
    dot = wx * bx + wy * by + wz * bz
    cross = (wy * bz - wz * by, wz * bx - wx * bz, wx * by - wy * bx)
    rotated = [
        b - sin_term * c + cos_term * (w * dot - b * n2)
        for b, c, w in zip((bx, by, bz), cross, (wx, wy, wz), strict=True)
    ]
    return torch.stack(rotated, -1)


def warp_events(
    problem: _Problem, omega: torch.Tensor, scale: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Events rotated to t_ref and projected at ``1/scale`` resolution.

    Returns (u, v, weight), each (N,) or (M, N) like ``omega``'s leading dims: pixel coordinates
    and the event's vote (its weight times the warp's area scale; 0 for rays turned backwards).
    """
    ray = rotate_bearings(problem.bearings, omega, problem.dt_s)
    z = ray[..., 2]
    valid = z > 0.1
    z = torch.where(valid, z, torch.ones_like(z))
    cam = problem.camera
    # Pixel centres sit at integer coordinates at every pyramid level.
    u = ((cam.fx * ray[..., 0] / z + cam.cx) + 0.5) / scale - 0.5
    v = ((cam.fy * ray[..., 1] / z + cam.cy) + 0.5) / scale - 0.5
    # A rotation homography scales image area by 1 / z'^3 (rays with z = 1). Voting with that
    # factor keeps warps from gaining contrast by squeezing events together in perspective.
    return u, v, problem.weights * valid * z**-3


def accumulate(
    u: torch.Tensor,
    v: torch.Tensor,
    weights: torch.Tensor,
    width: int,
    height: int,
    bilinear: bool = True,
) -> torch.Tensor:
    """Voting of points (u, v) (pixels) with ``weights`` into (..., height, width) images.

    Bilinear voting is differentiable in u, v and the weights; nearest-pixel voting (one vote
    per point, a quarter of the work) is for gradient-free scoring. Votes outside are dropped.
    """
    lead = u.shape[:-1]
    if not bilinear:
        return _accumulate_nearest(u, v, weights, width, height)
    u0 = torch.floor(u)
    v0 = torch.floor(v)
    fu = u - u0
    fv = v - v0
    u0 = u0.long()
    v0 = v0.long()
    batch = math.prod(lead)
    offset = torch.arange(batch).reshape(*lead, 1) * (width * height) if lead else 0
    image = u.new_zeros(batch * height * width)
    for du, dv, w in (
        (0, 0, (1 - fu) * (1 - fv)),
        (1, 0, fu * (1 - fv)),
        (0, 1, (1 - fu) * fv),
        (1, 1, fu * fv),
    ):
        x = u0 + du
        y = v0 + dv
        inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
        index = y.clamp(0, height - 1) * width + x.clamp(0, width - 1) + offset
        image = image.index_add(0, index.reshape(-1), (w * weights * inside).reshape(-1))
    return image.reshape(*lead, height, width)


def _accumulate_nearest(
    u: torch.Tensor, v: torch.Tensor, weights: torch.Tensor, width: int, height: int
) -> torch.Tensor:
    lead = u.shape[:-1]
    x = torch.round(u).long()
    y = torch.round(v).long()
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    batch = math.prod(lead)
    offset = torch.arange(batch).reshape(*lead, 1) * (width * height) if lead else 0
    index = (y * width + x + offset)[inside]
    votes = torch.broadcast_to(weights, u.shape)[inside]
    image = torch.bincount(index, votes, minlength=batch * height * width)
    return image.to(u.dtype).reshape(*lead, height, width)


@functools.lru_cache(maxsize=32)
def _blur_matrix(size: int, sigma: float) -> torch.Tensor:
    """(size, size) matrix of a 1-D Gaussian blur (σ in pixels, taps to 3σ, zero padding)."""
    radius = math.ceil(3 * sigma)
    taps = torch.exp(-0.5 * (torch.arange(-radius, radius + 1) / sigma) ** 2)
    taps = taps / taps.sum()
    offset = torch.arange(size)[:, None] - torch.arange(size)[None, :]
    return torch.where(offset.abs() <= radius, taps[(offset + radius).clamp(0, 2 * radius)], 0.0)


def smooth(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur (σ in pixels, zero padding) of (..., H, W) images.

    Two products with banded matrices: on CPU far faster than a one-channel conv2d over a batch
    of small images.
    """
    if sigma <= 0:
        return images
    height, width = images.shape[-2:]
    rows = _blur_matrix(height, float(sigma)).to(images.dtype)
    cols = _blur_matrix(width, float(sigma)).to(images.dtype)
    return rows @ images @ cols.T


def contrast(
    problem: _Problem, omega: torch.Tensor, scale: int, sigma: float, bilinear: bool = True
) -> torch.Tensor:
    """Variance of the smoothed IWE at ``1/scale`` resolution, one value per ω in ``omega``."""
    width = math.ceil(problem.width / scale)
    height = math.ceil(problem.height / scale)
    u, v, votes = warp_events(problem, omega, scale)
    image = smooth(accumulate(u, v, votes, width, height, bilinear), sigma)
    return image.flatten(-2).var(-1, unbiased=False)


def _grid(config: CMaxConfig) -> torch.Tensor:
    """(grid_points³, 3) angular velocities on a regular grid, rad/s."""
    axis = torch.linspace(-1.0, 1.0, config.grid_points)
    mesh = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    return mesh * math.radians(config.grid_max_dps)


def _grid_starts(problem: _Problem, config: CMaxConfig) -> list[torch.Tensor]:
    """The ``config.starts`` best grid points, scored on a coarse IWE smoothed to the spacing."""
    if config.starts <= 0:
        return []
    scale = config.levels[0]
    spacing = 2 * math.radians(config.grid_max_dps) / max(config.grid_points - 1, 1)
    # Wide enough that a sharp peak between grid points still lifts its neighbours.
    sigma = max(config.sigma_px, 0.5 * spacing * problem.px_per_rad_s / scale)
    candidates = _grid(config)
    with torch.no_grad():
        scores = torch.cat(
            [contrast(problem, c, scale, sigma, bilinear=False) for c in candidates.split(128)]
        )
    return list(candidates[torch.argsort(scores, descending=True)[: config.starts]])


def _refine(problem: _Problem, omega: torch.Tensor, scale: int, config: CMaxConfig) -> torch.Tensor:
    """Maximize the contrast at one pyramid level with L-BFGS; returns ω (3,) rad/s.

    The variable is ω in pixels of displacement at the window's ends (so one unit is about one
    pixel of blur on every axis) and the objective is normalized by its starting value, which
    makes L-BFGS's unit first step sensible for any window.
    """
    px = problem.px_per_rad_s
    phi = (omega * px).detach().clone().requires_grad_(True)
    with torch.no_grad():
        norm = float(contrast(problem, omega, scale, config.sigma_px))
    if norm <= 0:
        return omega
    opt = torch.optim.LBFGS(
        [phi],
        lr=1.0,
        max_iter=config.iterations,
        line_search_fn="strong_wolfe",
        tolerance_grad=1e-5,
        tolerance_change=1e-6,
    )

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = -contrast(problem, phi / px, scale, config.sigma_px) / norm
        loss.backward()
        return loss

    opt.step(closure)
    return phi.detach() / px


def _make_problem(
    events: EventArray, camera: Intrinsics, config: CMaxConfig, rng: np.random.Generator
) -> _Problem:
    if len(events) > config.max_events:
        events = events[np.sort(rng.choice(len(events), config.max_events, replace=False))]
    x = (events.x - camera.cx) / camera.fx
    y = (events.y - camera.cy) / camera.fy
    bearings = torch.from_numpy(np.stack([x, y, np.ones_like(x)], -1).astype(np.float32))
    t = events.t.astype(np.float64)
    dt_s = torch.from_numpy(((0.5 * (t[0] + t[-1]) - t) * 1e-6).astype(np.float32))
    if config.use_polarity:
        weights = torch.from_numpy(events.p.astype(np.float32) * 2.0 - 1.0)
    else:
        weights = torch.ones(len(events))
    return _Problem(bearings, dt_s, weights, camera, events.width, events.height)


@contextmanager
def _one_thread() -> Iterator[None]:
    """Run torch on one intra-op thread: the tensors here are small, and extra threads only add
    synchronization (and collapse under CPU contention)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def estimate_window(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    init: np.ndarray | None = None,
    grid: bool = True,
) -> np.ndarray:
    """The angular velocity (3,) rad/s, camera frame, that maximizes the contrast of ``events``.

    Args:
        events: one window of events (assumed to share one constant ω).
        camera: pinhole intrinsics in pixels; default :func:`default_camera` of the sensor.
        config: estimator settings; default :class:`CMaxConfig`.
        init: warm start (3,) rad/s, e.g. the previous window's estimate. With ``grid`` it
            competes with the best grid points, so a bad warm start cannot trap the estimate;
            without, it is refined at full resolution only (fast tracking).
        grid: run the coarse grid search (without it the search starts from ``init`` or 0).

    Returns:
        ω (3,) rad/s; ``init`` (or zeros) when the window holds fewer than ``config.min_events``
        events.
    """
    config = config or CMaxConfig()
    camera = camera or default_camera(events.width, events.height)
    fallback = np.zeros(3) if init is None else np.asarray(init, dtype=np.float64)
    if len(events) < max(config.min_events, 2) or events.t[-1] == events.t[0]:
        return fallback.copy()
    with _one_thread():
        return _estimate(events, camera, config, fallback, init is not None, grid)


def _estimate(
    events: EventArray,
    camera: Intrinsics,
    config: CMaxConfig,
    fallback: np.ndarray,
    warm: bool,
    grid: bool,
) -> np.ndarray:
    rng = np.random.default_rng(config.seed)
    problem = _make_problem(events, camera, config, rng)
    search = problem.subset(config.search_events, rng)
    starts = _grid_starts(search.subset(config.grid_events, rng), config) if grid else []
    if warm or not starts:
        starts.insert(0, torch.as_tensor(fallback, dtype=torch.float32))
    # A warm start without a grid search is already in the right basin: refine at full res only.
    levels = config.levels if grid or not warm else config.levels[-1:]
    finest = config.levels[-1]
    best, best_score = starts[0], -math.inf
    for omega in starts:
        for scale in levels[:-1]:
            omega = _refine(search, omega, scale, config)
        if len(starts) == 1:
            best = omega
            break
        with torch.no_grad():
            # Compared where blur no longer hides the difference between the candidates.
            score = float(contrast(search, omega, finest, config.sigma_px))
        if score > best_score:
            best, best_score = omega, score
    return _refine(problem, best, finest, config).double().numpy()


def window_start(events: EventArray, t_end_us: int, config: CMaxConfig) -> int:
    """Index of the first event of the window ending (exclusive) at ``t_end_us`` microseconds."""
    i1 = int(np.searchsorted(events.t, t_end_us, side="left"))
    i0 = int(np.searchsorted(events.t, t_end_us - round(config.window_ms * 1000), side="left"))
    if config.window_events and i1 - i0 < config.window_events:
        earliest = t_end_us - round(config.max_window_ms * 1000)
        i_min = int(np.searchsorted(events.t, earliest, side="left"))
        i0 = max(i_min, i1 - config.window_events)
    return i0


def predict_stream(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    *,
    t_first_us: int | None = None,
    t_end_us: int | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Estimate ω every ``config.stride_ms`` over a stream, each from the window ending there.

    Args:
        events: the event stream.
        camera: pinhole intrinsics, pixels; default :func:`default_camera` of the sensor.
        config: estimator settings.
        t_first_us: time of the first estimate, microseconds (default: first event + stride).
        t_end_us: no estimate after this time, microseconds (default: just after the last event).
        progress: optional callable ``progress(done, total)`` called after each estimate.

    Returns:
        ``(t_us, omega)``: estimate times (int64 µs; each uses only events with t < t_us) and
        (K, 3) ω in rad/s. Each estimate warm-starts the next.
    """
    config = config or CMaxConfig()
    camera = camera or default_camera(events.width, events.height)
    stride_us = config.stride_ms * 1000
    if len(events) == 0 and (t_first_us is None or t_end_us is None):
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    t_first = int(events.t[0]) + stride_us if t_first_us is None else int(t_first_us)
    t_end = int(events.t[-1]) + 1 if t_end_us is None else int(t_end_us)
    times = np.arange(t_first, t_end + 1, stride_us, dtype=np.int64)
    omegas = np.zeros((len(times), 3))
    history_us = int(events.t[0]) if len(events) else t_first
    previous, filling = None, True
    for k, t in enumerate(times):
        window = events[window_start(events, int(t), config) : int(np.searchsorted(events.t, t))]
        # Estimates from the short windows at a stream's start are the least reliable, so the
        # grid is searched until the window is full, then every grid_every estimates.
        grid = filling or (config.grid_every > 0 and k % config.grid_every == 0)
        previous = estimate_window(window, camera, config, init=previous, grid=grid)
        filling = t - config.window_ms * 1000 < history_us
        omegas[k] = previous
        if progress is not None:
            progress(k + 1, len(times))
    return times, omegas


def hold_per_ms(t_us: np.ndarray, omega: np.ndarray, t_start_us: int, num_steps: int) -> np.ndarray:
    """Per-ms predictions (num_steps, 3): each step holds the latest estimate made by its end.

    Step k is the bin ``[t_start + k ms, t_start + (k + 1) ms)``; it takes the last estimate with
    ``t_us <= t_start + (k + 1) ms`` (zeros before the first estimate).
    """
    ends = t_start_us + 1000 * (np.arange(num_steps, dtype=np.int64) + 1)
    index = np.searchsorted(t_us, ends, side="right") - 1
    held = np.zeros((num_steps, 3))
    held[index >= 0] = omega[index[index >= 0]]
    return held


def predict_windows(
    windows: Sequence[Any],
    config: CMaxConfig | None = None,
    camera: Intrinsics | None = None,
    progress: Progress | None = None,
    first_step: int = 0,
) -> np.ndarray:
    """Per-ms ω (n, T, 3) rad/s for ``spikegyro.train.data.Window`` objects (evaluation's API).

    Each window is streamed on its own (no events from outside it, as for the networks): an
    estimate at the end of step ``first_step`` and every ``config.stride_ms`` after, each from
    the events of the preceding ``config.window_ms`` (fewer at the window's start), held per ms
    as in :func:`hold_per_ms`. Steps before ``first_step`` are zero; pass the metrics' first step
    (50) to skip work that is not scored.

    Args:
        windows: objects with ``events`` (EventArray), ``omega`` (T, 3) and ``t_start_us``.
        config: estimator settings.
        camera: pinhole intrinsics (default :func:`default_camera` of the sensor).
        progress: optional callable ``progress(done, total)`` called after each window.
        first_step: first 1 ms step that gets an estimate.
    """
    config = config or CMaxConfig()
    out = []
    for n, window in enumerate(windows):
        num_steps = int(np.asarray(window.omega).shape[0])
        t0 = int(window.t_start_us)
        t_us, omega = predict_stream(
            window.events,
            camera,
            config,
            t_first_us=t0 + 1000 * (first_step + 1),
            t_end_us=t0 + 1000 * num_steps,
        )
        out.append(hold_per_ms(t_us, omega, t0, num_steps))
        if progress is not None:
            progress(n + 1, len(windows))
    return np.stack(out) if out else np.zeros((0, 0, 3))
