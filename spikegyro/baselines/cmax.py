"""Contrast maximization (Gallego and Scaramuzza, RA-L 2017): angular velocity without learning.

For a window of events and a candidate angular velocity ω (rad/s, camera frame: x right, y down,
z forward), every event's ray is rotated to a reference time ``t_ref`` in the middle of the
window, the rays are projected into an image of warped events (IWE) by bilinear voting, the IWE
is smoothed with a Gaussian, and the ω that maximizes its variance is the estimate: only the
true rotation brings the events of each edge back onto that edge (``cmax_iwe`` has the warp, the
objective and its exact gradient).

Rays. Events are undistorted to rays per sensor pixel with the sensor's calibration
(``spikegyro.events.calib.Calibration``; a plain pinhole when it has no distortion), in floating
point: no rounding onto a pixel grid and no event lost where the undistorted image overhangs the
sensor. Hot pixels are dropped (``cmax_windows.hot_pixel_mask``): they pull the estimate to 0.

Search. The variable is ω scaled to pixels of displacement at the window's ends, so one unit is
about one pixel of blur on each axis whatever the window's length. A grid over that space
(bounded by ``grid_max_dps`` and ``grid_max_px``), scored on a subsample at the coarsest pyramid
level with a blur as wide as the grid spacing, picks the best starts; each start (plus zero and
the warm start) is refined with L-BFGS coarse to fine on a subsample, the best at full resolution
wins, and it is refined on all events (up to ``max_events``). In a stream, each window starts
from the previous estimate and the full search is repeated every ``grid_every`` windows.

Windows (``cmax_windows``): by event count by default (``window_events`` events every
``stride_events``), each estimate standing for the middle of its window; or by time.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from spikegyro.baselines import cmax_iwe
from spikegyro.baselines.cmax_windows import count_windows, hot_pixel_mask, time_windows
from spikegyro.events.calib import DEFAULT_FOCAL_PX, DEFAULT_WIDTH, PinholeCamera
from spikegyro.events.core import EventArray

Progress = Callable[[int, int], Any]


class Intrinsics(Protocol):
    """Pinhole intrinsics in pixels (``PinholeCamera``, ``Calibration``, ``spikegyro.sim.Camera``).

    An object that also has ``pixel_rays(u, v)`` (a ``Calibration``) undistorts with it.
    """

    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class CMaxConfig:
    """Settings of the contrast-maximization estimator.

    Attributes:
        window_events: events per window (count windows; a shorter stream is one window).
        stride_events: events between consecutive count windows.
        window_ms: if > 0, windows of this duration (ms) instead of counts.
        stride_ms: time windows: one estimate every ``stride_ms`` ms.
        causal: time windows end at their estimate's time (only past events) instead of being
            centred on it.
        max_events: windows with more events are randomly subsampled to this many (speed).
        min_events: windows with fewer events keep the previous estimate (zero at the start).
        hot_pixel_factor: drop pixels firing more than this times the 95th percentile of
            the pixel counts (see ``cmax_windows.hot_pixel_mask``); 0 keeps all.
        levels: image downscale factors of the pyramid, coarse to fine (the last is 1).
        sigma_px: Gaussian smoothing of the IWE, pixels of each pyramid level.
        iterations: L-BFGS iterations per pyramid level.
        grid_points: grid points per axis of the global search (odd, so 0 is on the grid).
        grid_max_dps: the grid spans at most ``±grid_max_dps`` deg/s on each axis ...
        grid_max_px: ... and at most ``±grid_max_px`` pixels of displacement at the window's ends.
        grid_events: events (random subsample) scored by the grid.
        starts: how many of the best grid points are refined (besides zero and the warm start).
        grid_every: in a stream, search globally every ``grid_every`` windows (always for the
            first); between, start from the previous estimate only. 0: only the first.
        search_events: events (random subsample) used to refine and compare the starts.
        seed: seed of the event subsampling.
    """

    window_events: int = 30_000
    stride_events: int = 10_000
    window_ms: float = 0.0
    stride_ms: float = 5.0
    causal: bool = False
    max_events: int = 30_000
    min_events: int = 100
    hot_pixel_factor: float = 5.0
    levels: tuple[int, ...] = (4, 2, 1)
    sigma_px: float = 1.0
    iterations: int = 20
    grid_points: int = 11
    grid_max_dps: float = 1000.0
    grid_max_px: float = 40.0
    grid_events: int = 2000
    starts: int = 3
    grid_every: int = 10
    search_events: int = 4000
    seed: int = 0


@dataclass(frozen=True)
class _Problem:
    """One window ready for warping: rays, times to t_ref, and the pinhole to project with."""

    bx: np.ndarray  # (N,) ray x/z
    by: np.ndarray  # (N,) ray y/z
    dt: np.ndarray  # (N,) t_ref - t, seconds
    weights: np.ndarray  # (N,) votes
    intrinsics: np.ndarray  # fx, fy, cx, cy
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.dt)

    def subset(self, n: int, rng: np.random.Generator) -> _Problem:
        """At most ``n`` events drawn at random (the same problem when it has no more)."""
        if len(self) <= n:
            return self
        keep = np.sort(rng.choice(len(self), n, replace=False))
        return replace(
            self, bx=self.bx[keep], by=self.by[keep], dt=self.dt[keep], weights=self.weights[keep]
        )

    @property
    def px_per_rad_s(self) -> float:
        """Image displacement (px) that 1 rad/s causes at the window's ends: ω's natural scale."""
        half_span = float(np.abs(self.dt).max()) if len(self) else 0.0
        return max(half_span, 1e-4) * float(self.intrinsics[0])

    def contrast(
        self, omega: np.ndarray, scale: int, sigma: float, gradient: bool = False
    ) -> tuple[float, np.ndarray]:
        """IWE variance at ``1/scale`` resolution (and its gradient in 1/(rad/s))."""
        return cmax_iwe.contrast(
            self.bx,
            self.by,
            self.dt,
            self.weights,
            np.asarray(omega, dtype=np.float64),
            self.intrinsics,
            float(scale),
            math.ceil(self.width / scale),
            math.ceil(self.height / scale),
            cmax_iwe.gaussian_taps(sigma),
            gradient,
        )


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


@functools.lru_cache(maxsize=8)
def _ray_table(camera: Any, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(height, width) ray x/z and y/z of every sensor pixel: undistorted, NaN where undefined.

    ``camera``: a ``Calibration`` or a tuple ``(fx, fy, cx, cy)``.
    """
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    if hasattr(camera, "pixel_rays"):
        xn, yn = camera.pixel_rays(u, v)
    else:
        fx, fy, cx, cy = camera
        xn, yn = (u - cx) / fx, (v - cy) / fy
    return np.asarray(xn), np.asarray(yn)


def make_problem(
    events: EventArray,
    camera: Intrinsics,
    config: CMaxConfig,
    rng: np.random.Generator,
    t_ref_us: float | None = None,
) -> _Problem:
    """Rays of ``events`` (hot pixels dropped, subsampled to ``max_events``) around ``t_ref_us``.

    ``t_ref_us`` defaults to the middle of the events' span.
    """
    keep = hot_pixel_mask(events.x, events.y, events.width, events.height, config.hot_pixel_factor)
    # Keyed by value: a calibration undistorts, any other intrinsics are a plain pinhole.
    key = camera if hasattr(camera, "pixel_rays") else (camera.fx, camera.fy, camera.cx, camera.cy)
    xs, ys = _ray_table(key, events.width, events.height)
    ix, iy = events.x.astype(np.intp), events.y.astype(np.intp)
    bx, by = xs[iy, ix], ys[iy, ix]
    keep &= np.isfinite(bx) & np.isfinite(by)
    index = np.flatnonzero(keep)
    if len(index) > config.max_events:
        index = np.sort(rng.choice(index, config.max_events, replace=False))
    t = events.t.astype(np.float64)
    t_ref = 0.5 * (t[0] + t[-1]) if t_ref_us is None else float(t_ref_us)
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy], dtype=np.float64)
    return _Problem(
        bx[index],
        by[index],
        (t_ref - t[index]) * 1e-6,
        np.ones(len(index)),
        intrinsics,
        events.width,
        events.height,
    )


def _grid_starts(problem: _Problem, config: CMaxConfig) -> list[np.ndarray]:
    """The ``config.starts`` best grid points, scored at the coarsest level blurred to spacing."""
    if config.starts <= 0 or config.grid_points < 2:
        return []
    px = problem.px_per_rad_s
    reach = min(math.radians(config.grid_max_dps), config.grid_max_px / px)
    axis = np.linspace(-reach, reach, config.grid_points)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    scale = config.levels[0]
    spacing_px = (axis[1] - axis[0]) * px / scale
    # Wide enough that a sharp peak between grid points still lifts its neighbours.
    sigma = max(config.sigma_px, 0.5 * spacing_px)
    scores = cmax_iwe.contrast_batch(
        problem.bx,
        problem.by,
        problem.dt,
        problem.weights,
        grid,
        problem.intrinsics,
        float(scale),
        math.ceil(problem.width / scale),
        math.ceil(problem.height / scale),
        cmax_iwe.gaussian_taps(sigma),
    )
    return list(grid[np.argsort(-scores)[: config.starts]])


def maximize_bfgs(
    objective: Callable[[np.ndarray], tuple[float, np.ndarray]],
    x0: np.ndarray,
    iterations: int,
    first_step: float = 1.0,
    xtol: float = 1e-3,
) -> np.ndarray:
    """Maximize a smooth function of a few variables by BFGS with a backtracking line search.

    ``objective(x)`` returns the value and its gradient. The first step moves ``first_step``
    along the gradient; the inverse Hessian then takes over. Stops after ``iterations`` steps,
    when a step is shorter than ``xtol`` on every variable, or when no step gains.

    (SciPy's L-BFGS-B driver spends milliseconds per iteration in multithreaded BLAS calls
    under CPU contention, more than the objective itself costs here.)
    """
    x = np.asarray(x0, dtype=np.float64)
    f, g = objective(x)
    inv_hessian = np.eye(len(x)) * first_step / max(float(np.linalg.norm(g)), 1e-30)
    for _ in range(iterations):
        direction = inv_hessian @ g
        slope = float(g @ direction)
        if not slope > 0:
            inv_hessian = np.eye(len(x)) * first_step / max(float(np.linalg.norm(g)), 1e-30)
            direction, slope = inv_hessian @ g, first_step * float(np.linalg.norm(g))
        step = 1.0
        while True:
            x_new = x + step * direction
            f_new, g_new = objective(x_new)
            if f_new >= f + 1e-4 * step * slope:
                break
            step *= 0.3
            if step * float(np.abs(direction).max()) < xtol:
                return x
        s, y = x_new - x, g - g_new  # y: change of the gradient of -objective
        x, f, g = x_new, f_new, g_new
        sy = float(s @ y)
        if sy > 1e-12:
            rho = 1.0 / sy
            left = np.eye(len(x)) - rho * np.outer(s, y)
            inv_hessian = left @ inv_hessian @ left.T + rho * np.outer(s, s)
        if float(np.abs(s).max()) < xtol:
            break
    return x


def _refine(problem: _Problem, omega: np.ndarray, scale: int, config: CMaxConfig) -> np.ndarray:
    """Maximize the contrast at one pyramid level from ``omega``; returns ω rad/s.

    The variable is ω in pixels of displacement at the window's ends (at this level) and the
    objective is normalized by its starting value, so steps and tolerances mean the same in
    any window: the first step is half a pixel, and a step under 0.01 px ends the search.
    """
    px = problem.px_per_rad_s / scale
    norm = problem.contrast(omega, scale, config.sigma_px)[0]
    if not norm > 0:
        return omega

    def objective(phi: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = problem.contrast(phi / px, scale, config.sigma_px, gradient=True)
        return value / norm, grad / (norm * px)

    phi = maximize_bfgs(objective, np.asarray(omega) * px, config.iterations, 0.5, 0.01)
    return phi / px


def estimate_window(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    init: np.ndarray | None = None,
    grid: bool = True,
    t_ref_us: float | None = None,
) -> np.ndarray:
    """The angular velocity (3,) rad/s, camera frame, that maximizes the contrast of ``events``.

    Args:
        events: one window of events (assumed to share one constant ω), on the sensor's pixels.
        camera: the sensor's intrinsics in pixels, or its ``Calibration`` (then the events are
            undistorted); default :func:`default_camera` of the sensor.
        config: estimator settings; default :class:`CMaxConfig`.
        init: warm start (3,) rad/s, e.g. the previous window's estimate. With ``grid`` it
            competes with the best grid points and zero, so a bad warm start cannot trap the
            estimate; without, it is refined at the two finest levels only (fast tracking).
        grid: run the global search (without it the search starts from ``init`` or 0).
        t_ref_us: the time the estimate stands for, µs (default: the middle of the events).

    Returns:
        ω (3,) rad/s; ``init`` (or zeros) when the window holds fewer than ``config.min_events``
        events.
    """
    config = config or CMaxConfig()
    camera = camera or default_camera(events.width, events.height)
    fallback = np.zeros(3) if init is None else np.asarray(init, dtype=np.float64)
    if len(events) < max(config.min_events, 2) or events.t[-1] == events.t[0]:
        return fallback.copy()
    rng = np.random.default_rng(config.seed)
    problem = make_problem(events, camera, config, rng, t_ref_us)
    if len(problem) < max(config.min_events, 2):
        return fallback.copy()
    search = problem.subset(config.search_events, rng)
    finest = config.levels[-1]
    if grid or init is None:
        starts = _grid_starts(search.subset(config.grid_events, rng), config) if grid else []
        starts += [np.zeros(3)] + ([fallback] if init is not None else [])
        levels = config.levels
    else:
        starts, levels = [fallback], config.levels[-2:]
    best, best_score = starts[0], -math.inf
    for omega in starts:
        for scale in levels[:-1]:
            omega = _refine(search, omega, scale, config)
        if len(starts) == 1:
            best = omega
            break
        # Compared where blur no longer hides the difference between the candidates.
        score = search.contrast(omega, finest, config.sigma_px)[0]
        if score > best_score:
            best, best_score = omega, score
    return _refine(problem, best, finest, config)


def plan_windows(
    events: EventArray,
    config: CMaxConfig,
    t_first_us: int | None = None,
    t_end_us: int | None = None,
) -> np.ndarray:
    """The windows a stream is estimated over: (K, 3) int64 rows ``(i0, i1, t_ref_us)``.

    Count windows (``config.window_ms == 0``) cover all events; only those whose reference time
    lies in ``[t_first_us, t_end_us]`` are kept. Time windows are placed every ``stride_ms``
    from ``t_first_us`` to ``t_end_us``; by default from the first event plus a stride (causal)
    or half a window (centred) to the last event (less half a window when centred; a stream
    shorter than that gets one window at its middle).
    """
    t = events.t
    if len(t) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    lo = int(t[0]) if t_first_us is None else int(t_first_us)
    hi = int(t[-1]) + 1 if t_end_us is None else int(t_end_us)
    if config.window_ms <= 0:
        rows = count_windows(t, config.window_events, config.stride_events)
        return rows[(rows[:, 2] >= lo) & (rows[:, 2] <= hi)]
    stride_us = max(round(config.stride_ms * 1000), 1)
    # By default centred windows stay inside the stream; one shorter than a window gets one.
    half = 0 if config.causal else round(config.window_ms * 500)
    if t_first_us is None:
        lo += stride_us if config.causal else half
    if t_end_us is None:
        hi -= half
    times = np.arange(lo, hi + 1, stride_us, dtype=np.int64)
    if not len(times) and t_first_us is None and t_end_us is None:
        times = np.array([(int(t[0]) + int(t[-1])) // 2], dtype=np.int64)
    return time_windows(t, round(config.window_ms * 1000), times, config.causal)


def predict_stream(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    *,
    t_first_us: int | None = None,
    t_end_us: int | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Estimate ω over a stream, one estimate per window of :func:`plan_windows`.

    Args:
        events: the event stream, on the sensor's pixels.
        camera: the sensor's intrinsics or ``Calibration``; default :func:`default_camera`.
        config: estimator settings (windows by count by default).
        t_first_us, t_end_us: keep estimates whose reference time is in this range, µs.
        progress: optional callable ``progress(done, total)`` called after each estimate.

    Returns:
        ``(t_us, omega)``: each window's reference time (int64 µs: the middle of the window, or
        its end for causal time windows) and its ω (K, 3) rad/s. Each estimate warm-starts the
        next; the global search runs on the first window and every ``grid_every`` windows.
    """
    config = config or CMaxConfig()
    camera = camera or default_camera(events.width, events.height)
    rows = plan_windows(events, config, t_first_us, t_end_us)
    omegas = np.zeros((len(rows), 3))
    previous: np.ndarray | None = None
    searched = False
    for k, (i0, i1, t_ref) in enumerate(rows):
        window = events[int(i0) : int(i1)]
        # Until a window has been searched globally there is nothing to track.
        grid = not searched or (config.grid_every > 0 and k % config.grid_every == 0)
        ref = None if config.causal else t_ref
        previous = estimate_window(window, camera, config, init=previous, grid=grid, t_ref_us=ref)
        searched |= grid and len(window) >= config.min_events
        omegas[k] = previous
        if progress is not None:
            progress(k + 1, len(rows))
    return rows[:, 2].copy(), omegas


def per_ms(t_us: np.ndarray, omega: np.ndarray, times_us: np.ndarray) -> np.ndarray:
    """Estimates at reference times ``t_us`` linearly interpolated onto ``times_us`` (µs).

    Constant beyond the first and last estimates; zeros when there is none.
    """
    if len(t_us) == 0:
        return np.zeros((len(times_us), 3))
    return np.column_stack([np.interp(times_us, t_us, omega[:, k]) for k in range(3)])


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


SIMULATED_CONFIG = CMaxConfig(window_ms=30.0, stride_ms=5.0, causal=True)
"""Causal 30 ms windows every 5 ms: the networks' setting in ``spikegyro evaluate``."""


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
        config: estimator settings, causal time windows (default :data:`SIMULATED_CONFIG`).
        camera: pinhole intrinsics (default :func:`default_camera` of the sensor).
        progress: optional callable ``progress(done, total)`` called after each window.
        first_step: first 1 ms step that gets an estimate.
    """
    config = config or SIMULATED_CONFIG
    if config.window_ms <= 0 or not config.causal:
        raise ValueError("predict_windows needs causal time windows (window_ms > 0, causal).")
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
