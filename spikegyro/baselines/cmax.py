"""Contrast maximization (Gallego and Scaramuzza, RA-L 2017): angular velocity without learning.

For a window of events and a candidate angular velocity ω (rad/s, camera frame: x right, y down,
z forward), every event's ray is rotated to a reference time ``t_ref``, the rays are projected
into an image of warped events (IWE) by bilinear voting, the IWE is smoothed with a Gaussian,
and the ω that maximizes its variance is the estimate: only the true rotation brings the events
of each edge back onto that edge (``cmax_iwe`` has the warp, the objective and its exact
gradient).

Rays. Events are undistorted to rays per sensor pixel with the sensor's calibration
(``spikegyro.events.calib.Calibration``; a plain pinhole when it has no distortion), in floating
point: no rounding onto a pixel grid and no event lost where the undistorted image overhangs the
sensor. Hot pixels are dropped (``cmax_windows``): they pull the estimate to 0.

Search (:func:`search`). The variable is ω scaled to pixels of displacement at the window's
far end, so one unit is about one pixel of blur on each axis whatever the window's length. A
grid over that space (bounded by ``grid_max_dps`` and ``grid_max_px``), scored on a subsample at
the coarsest pyramid level with a blur as wide as the grid spacing, picks the best starts; each
start (plus zero and the warm start) is refined with BFGS coarse to fine on a subsample, the
best at full resolution wins, and it is refined on all events (up to ``max_events``).

Streams (:mod:`spikegyro.baselines.cmax_stream`): causal windows that adapt to the event rate
and the motion (:mod:`spikegyro.baselines.cmax_windows`), one estimate per output time, each
warm-started from the previous one and refined by a few BFGS steps at full resolution, with the
global search at the start and every ``search_every_s``. :func:`predict_stream` and
:func:`predict_windows` run it over events in memory.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from spikegyro.baselines import cmax_iwe
from spikegyro.baselines.cmax_windows import WindowPolicy, hot_pixel_mask
from spikegyro.events.calib import DEFAULT_FOCAL_PX, DEFAULT_WIDTH, PinholeCamera
from spikegyro.events.core import EventArray
from spikegyro.events.windows import BIN_US, series_per_window

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

    Streams (:class:`~spikegyro.baselines.cmax_stream.CMaxEstimator`):
        rate_hz: estimates per second of event time; 0: one per event batch.
        window: how long each causal window is (adaptive by default; see ``WindowPolicy``).
        track_events: events (evenly thinned) a tracking estimate uses at most (speed).
        track_iterations: BFGS iterations of a tracking estimate (warm-started, curvature
            included).
        track_xtol_px: a tracking estimate stops once a step moves edges less than this, px.
        search_every_s: the global search runs at the first estimate and then every this many
            seconds of event time (0: only at the first), the tracked estimate competing.
        min_motion_px: estimates moving edges by less than this over their window are flagged
            ill-posed (too little motion to tell from none).
        gain_drop: when an estimate's contrast gain above 1 falls below this share of its
            recent best, or it is ill-posed, the next search comes after a fifth of
            ``search_every_s``; below half this share, at the next estimate.

    One window (:func:`estimate_window`, :func:`search`):
        max_events: windows with more events are randomly subsampled to this many (speed).
        min_events: windows with fewer events give no estimate (the previous one, or zero).
        hot_pixel_factor: drop pixels firing more than this times the 95th percentile of
            the pixel counts (see ``cmax_windows``); 0 keeps all.
        levels: image downscale factors of the pyramid, coarse to fine (the last is 1).
        sigma_px: Gaussian smoothing of the IWE, pixels of each pyramid level.
        iterations: BFGS iterations per pyramid level of the search.
        grid_points: grid points per axis of the global search (odd, so 0 is on the grid).
        grid_max_dps: the grid spans at most ``±grid_max_dps`` deg/s on each axis ...
        grid_max_px: ... and at most ``±grid_max_px`` pixels of displacement at the window's ends.
        grid_events: events (random subsample) scored by the grid.
        starts: how many of the best grid points are refined (besides zero and the warm start).
        search_events: events (random subsample) used to refine and compare the starts.
        seed: seed of the event subsampling.
    """

    rate_hz: float = 100.0
    window: WindowPolicy = field(default_factory=WindowPolicy)
    track_events: int = 10_000
    track_iterations: int = 2
    track_xtol_px: float = 0.05
    search_every_s: float = 1.0
    min_motion_px: float = 1.0
    gain_drop: float = 0.6
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
    search_events: int = 4000
    seed: int = 0


@dataclass(frozen=True)
class Problem:
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

    def subset(self, n: int, rng: np.random.Generator) -> Problem:
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
def ray_table(camera: Any, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
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
) -> Problem:
    """Rays of ``events`` (hot pixels dropped, subsampled to ``max_events``) around ``t_ref_us``.

    ``t_ref_us`` defaults to the middle of the events' span.
    """
    keep = hot_pixel_mask(events.x, events.y, events.width, events.height, config.hot_pixel_factor)
    # Keyed by value: a calibration undistorts, any other intrinsics are a plain pinhole.
    key = camera if hasattr(camera, "pixel_rays") else (camera.fx, camera.fy, camera.cx, camera.cy)
    xs, ys = ray_table(key, events.width, events.height)
    ix, iy = events.x.astype(np.intp), events.y.astype(np.intp)
    bx, by = xs[iy, ix], ys[iy, ix]
    keep &= np.isfinite(bx) & np.isfinite(by)
    index = np.flatnonzero(keep)
    if len(index) > config.max_events:
        index = np.sort(rng.choice(index, config.max_events, replace=False))
    t = events.t.astype(np.float64)
    t_ref = 0.5 * (t[0] + t[-1]) if t_ref_us is None else float(t_ref_us)
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy], dtype=np.float64)
    return Problem(
        bx[index],
        by[index],
        (t_ref - t[index]) * 1e-6,
        np.ones(len(index)),
        intrinsics,
        events.width,
        events.height,
    )


def _grid_starts(problem: Problem, config: CMaxConfig) -> list[np.ndarray]:
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


@dataclass(frozen=True)
class Maximum:
    """What :func:`maximize_bfgs` found: the point, its value, the final inverse Hessian
    estimate (of the negated objective) and how many times the objective was evaluated."""

    x: np.ndarray
    value: float
    inv_hessian: np.ndarray
    evaluations: int


def maximize_bfgs(
    objective: Callable[[np.ndarray], tuple[float, np.ndarray]],
    x0: np.ndarray,
    iterations: int,
    first_step: float = 1.0,
    xtol: float = 1e-3,
    inv_hessian: np.ndarray | None = None,
    start: tuple[float, np.ndarray] | None = None,
) -> Maximum:
    """Maximize a smooth function of a few variables by BFGS with a backtracking line search.

    ``objective(x)`` returns the value and its gradient; ``start`` is that pair at ``x0`` when
    already known. Without ``inv_hessian`` (a previous run's, to warm-start the curvature too)
    the first step moves ``first_step`` along the gradient; the inverse Hessian then takes over.
    Stops after ``iterations`` steps, when a step is shorter than ``xtol`` on every variable, or
    when no step gains.

    (SciPy's L-BFGS-B driver spends milliseconds per iteration in multithreaded BLAS calls
    under CPU contention, more than the objective itself costs here.)
    """
    x = np.asarray(x0, dtype=np.float64)
    f, g = objective(x) if start is None else start
    calls = int(start is None)
    eye = np.eye(len(x))

    def gradient_step() -> np.ndarray:
        return eye * first_step / max(float(np.linalg.norm(g)), 1e-30)

    h = gradient_step() if inv_hessian is None else np.array(inv_hessian, dtype=np.float64)
    for _ in range(iterations):
        direction = h @ g
        slope = float(g @ direction)
        if not slope > 0:
            h = gradient_step()
            direction, slope = h @ g, first_step * float(np.linalg.norm(g))
        step = 1.0
        while True:
            x_new = x + step * direction
            f_new, g_new = objective(x_new)
            calls += 1
            if f_new >= f + 1e-4 * step * slope:
                break
            step *= 0.3
            if step * float(np.abs(direction).max()) < xtol:
                return Maximum(x, f, h, calls)
        s, y = x_new - x, g - g_new  # y: change of the gradient of -objective
        x, f, g = x_new, f_new, g_new
        sy = float(s @ y)
        if sy > 1e-12:
            rho = 1.0 / sy
            left = eye - rho * np.outer(s, y)
            h = left @ h @ left.T + rho * np.outer(s, s)
        if float(np.abs(s).max()) < xtol:
            break
    return Maximum(x, f, h, calls)


@dataclass(frozen=True)
class Refined:
    """ω (3,) rad/s from :func:`refine`, its contrast, and the curvature to warm-start with
    (inverse Hessian in normalized units: pixels at the window's far end, contrast over the
    starting contrast)."""

    omega: np.ndarray
    contrast: float
    inv_hessian: np.ndarray | None


def refine(
    problem: Problem,
    omega: np.ndarray,
    scale: int,
    config: CMaxConfig,
    iterations: int | None = None,
    inv_hessian: np.ndarray | None = None,
    xtol_px: float = 0.01,
) -> Refined:
    """Maximize the contrast at one pyramid level from ``omega`` (rad/s).

    The variable is ω in pixels of displacement at the window's far end (at this level) and the
    objective is normalized by its starting value, so steps, tolerances and curvature mean the
    same in any window: the first step is half a pixel (without ``inv_hessian``), and a step
    under ``xtol_px`` ends the search.
    """
    px = problem.px_per_rad_s / scale
    omega = np.asarray(omega, dtype=np.float64)
    norm, grad = problem.contrast(omega, scale, config.sigma_px, gradient=True)
    if not norm > 0:
        return Refined(omega, norm, None)

    def objective(phi: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = problem.contrast(phi / px, scale, config.sigma_px, gradient=True)
        return value / norm, grad / (norm * px)

    steps = config.iterations if iterations is None else iterations
    found = maximize_bfgs(
        objective, omega * px, steps, 0.5, xtol_px, inv_hessian, (1.0, grad / (norm * px))
    )
    return Refined(found.x / px, found.value * norm, found.inv_hessian)


def search(
    problem: Problem,
    config: CMaxConfig,
    init: np.ndarray | None = None,
    grid: bool = True,
    rng: np.random.Generator | None = None,
) -> Refined:
    """The ω (3,) rad/s that maximizes the contrast of ``problem``'s events (see Refined).

    With ``grid`` (or without ``init``), the best grid points, zero and ``init`` are refined
    coarse to fine on a subsample and the best is refined on all events, so a bad warm start
    cannot trap the estimate; otherwise ``init`` is refined at the two finest levels.
    """
    rng = rng or np.random.default_rng(config.seed)
    sub = problem.subset(config.search_events, rng)
    finest = config.levels[-1]
    if grid or init is None:
        starts = _grid_starts(sub.subset(config.grid_events, rng), config) if grid else []
        starts += [np.zeros(3)] + ([np.asarray(init, dtype=np.float64)] if init is not None else [])
        levels = config.levels
    else:
        starts, levels = [np.asarray(init, dtype=np.float64)], config.levels[-2:]
    best, best_score = starts[0], -math.inf
    for omega in starts:
        for scale in levels[:-1]:
            omega = refine(sub, omega, scale, config).omega
        if len(starts) == 1:
            best = omega
            break
        # Compared where blur no longer hides the difference between the candidates.
        score = sub.contrast(omega, finest, config.sigma_px)[0]
        if score > best_score:
            best, best_score = omega, score
    return refine(problem, best, finest, config)


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
        init: warm start (3,) rad/s, e.g. the previous window's estimate (see :func:`search`).
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
    return search(problem, config, init, grid, rng).omega


def predict_stream(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    *,
    t_first_us: int | None = None,
    t_end_us: int | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Causal estimates over a stream in memory (the engine of ``spikegyro predict --method
    cmax``), one every ``1 / config.rate_hz`` s.

    Args:
        events: the event stream, on the sensor's pixels.
        camera: the sensor's intrinsics or ``Calibration``; default :func:`default_camera`.
        config: estimator settings (adaptive causal windows at 100 Hz by default).
        t_first_us: the output clock's origin (estimates at ``t_first + k / rate``, k >= 1);
            default the first event's whole millisecond.
        t_end_us: no estimates after this time, µs (default: the last event).
        progress: optional callable ``progress(done, total)`` called after each batch.

    Returns:
        ``(t_us, omega)``: each estimate's time (int64 µs; it uses events up to it) and its ω
        (K, 3) rad/s.
    """
    from spikegyro.baselines.cmax_stream import CMaxEstimator

    estimator = CMaxEstimator(camera, config, t0_us=t_first_us)
    est = estimator.run(events, t_end_us, progress)
    return est.t_us, est.omega


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
    ends = t_start_us + BIN_US * (np.arange(num_steps, dtype=np.int64) + 1)
    index = np.searchsorted(t_us, ends, side="right") - 1
    held = np.zeros((num_steps, 3))
    held[index >= 0] = omega[index[index >= 0]]
    return held


SIMULATED_CONFIG = CMaxConfig(rate_hz=200.0, window=WindowPolicy(fixed_ms=30.0))
"""Causal 30 ms windows every 5 ms: the networks' setting in ``spikegyro evaluate``."""


def predict_windows(
    windows: Sequence[Any],
    config: CMaxConfig | None = None,
    camera: Intrinsics | None = None,
    progress: Progress | None = None,
    first_step: int = 0,
) -> np.ndarray:
    """Per-ms ω (n, T, 3) rad/s for ``spikegyro.train.data.Window`` objects (evaluation's API).

    Each window is streamed on its own (no events from outside it, as for the networks), with
    estimates every ``1 / config.rate_hz`` s from its start, each from the events before it
    (fewer at the window's start), held per ms as in :func:`hold_per_ms`. Steps before
    ``first_step`` are zero; pass the metrics' first step (50) to skip work that is not scored.

    Args:
        windows: objects with ``events`` (EventArray), ``omega`` (T, 3) and ``t_start_us``.
        config: estimator settings (default :data:`SIMULATED_CONFIG`).
        camera: pinhole intrinsics (default :func:`default_camera` of the sensor).
        progress: optional callable ``progress(done, total)`` called after each window.
        first_step: first 1 ms step that gets an estimate.
    """
    config = config or SIMULATED_CONFIG

    def held(batch: Sequence[Any]) -> np.ndarray:
        (window,) = batch  # one at a time: each window is streamed on its own
        steps = int(np.asarray(window.omega).shape[0])
        t0 = int(window.t_start_us)
        t_us, omega = predict_stream(
            window.events, camera, config, t_first_us=t0, t_end_us=t0 + BIN_US * steps
        )
        keep = t_us > t0 + BIN_US * first_step
        series = hold_per_ms(t_us[keep], omega[keep], t0, steps)
        series[:first_step] = 0.0
        return series[None]

    num_steps = int(np.asarray(windows[0].omega).shape[0]) if len(windows) else 0
    done = None if progress is None else lambda n: progress(n, len(windows))
    return series_per_window(held, windows, num_steps, progress=done)
