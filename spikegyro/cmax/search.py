"""Contrast maximization of one window (Gallego and Scaramuzza, RA-L 2017): the ω that
maximizes the contrast of the image of warped events, by global search and BFGS.

For a window of events and a candidate angular velocity ω (rad/s, camera frame: x right, y down,
z forward), every event's ray is rotated to a reference time ``t_ref``, the rays are projected
into an image of warped events (IWE) by bilinear voting, the IWE is smoothed with a Gaussian,
and the ω that maximizes its variance is the estimate: only the true rotation brings the events
of each edge back onto that edge (:mod:`spikegyro.cmax.iwe` has the warp, the objective and its
exact gradient).

Search (:func:`search`). The variable is ω scaled to pixels of displacement at the window's
far end, so one unit is about one pixel of blur on each axis whatever the window's length. A
grid over that space (bounded by ``grid_max_dps`` and ``grid_max_px``), scored on a subsample at
the coarsest pyramid level with a blur as wide as the grid spacing, picks the best starts; each
start (plus zero and the warm start) is refined with BFGS coarse to fine on a subsample, the
best at full resolution wins, and it is refined on all events (up to ``max_events``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from spikegyro.cmax import iwe
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.problem import Intrinsics, Problem, default_camera, make_problem
from spikegyro.events.core import EventArray


def grid_of(problem: Problem, config: CMaxConfig) -> tuple[np.ndarray, tuple]:
    """The global search's grid (M, 3) rad/s and the arguments after the ω of the objective
    that scores it: the intrinsics, the coarsest level, its image size and a blur as wide as
    the grid's spacing."""
    px = problem.px_per_rad_s
    reach = min(math.radians(config.grid_max_dps), config.grid_max_px / px)
    axis = np.linspace(-reach, reach, config.grid_points)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    scale = problem.level(config.levels[0])
    # Wide enough that a sharp peak between grid points still lifts its neighbours.
    sigma = max(config.sigma_px, 0.5 * (axis[1] - axis[0]) * px / scale)
    size = (math.ceil(problem.width / scale), math.ceil(problem.height / scale))
    return grid, (problem.intrinsics, float(scale), *size, iwe.gaussian_taps(sigma))


def _grid_starts(problem: Problem, config: CMaxConfig) -> list[np.ndarray]:
    """The ``config.starts`` best grid points, scored at the coarsest level blurred to spacing."""
    if config.starts <= 0 or config.grid_points < 2:
        return []
    grid, rest = grid_of(problem, config)
    p = problem
    scores = iwe.grid_contrast(p.bx, p.by, p.dt, p.weights, grid, *rest)
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
    # A gradient step's h says nothing of the curvature (its scale, 1/|g|, grows without bound
    # near the maximum): the first update rescales it by the curvature measured along the step.
    measured = inv_hessian is not None
    for _ in range(iterations):
        direction = h @ g
        slope = float(g @ direction)
        if not slope > 0:
            h, measured = gradient_step(), False
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
            if not measured:
                h, measured = eye * (sy / float(y @ y)), True  # Nocedal & Wright (6.20)
            rho = 1.0 / sy
            left = eye - rho * np.outer(s, y)
            h = left @ h @ left.T + rho * np.outer(s, s)
        if float(np.abs(s).max()) < xtol:
            break
    return Maximum(x, f, h, calls)


@dataclass(frozen=True)
class Refined:
    """ω (3,) rad/s (or ω and α (6,), see :func:`refine`) from :func:`refine`, its contrast,
    and the curvature to warm-start with (inverse Hessian in normalized units: pixels at the
    window's far end, contrast over the starting contrast)."""

    omega: np.ndarray
    contrast: float
    inv_hessian: np.ndarray | None


def _units(problem: Problem, size: int, scale: int) -> np.ndarray:
    """Pixels of displacement at the window's far end (this level's pixels, binning included)
    per unit of each variable: ω (rad/s), then α (rad/s²) when ``size`` is 6."""
    px = problem.px_per_rad_s / problem.level(scale)
    if size == 3:
        return np.full(3, px)
    span = problem.px_per_rad_s / float(problem.intrinsics[0])  # s
    return np.r_[np.full(3, px), np.full(3, 0.5 * span * px)]


def refine(
    problem: Problem,
    omega: np.ndarray,
    scale: int,
    config: CMaxConfig,
    iterations: int | None = None,
    inv_hessian: np.ndarray | None = None,
    xtol_px: float = 0.01,
    bend_cost: float = 0.0,
) -> Refined:
    """Maximize the contrast at one pyramid level from ``omega`` (rad/s).

    The variable is ω in pixels of displacement at the window's far end (in this level's
    pixels, binning included) and the
    objective is normalized by its starting value, so steps, tolerances and curvature mean the
    same in any window: the first step is half a pixel (without ``inv_hessian``), and a step
    under ``xtol_px`` ends the search.

    ``omega`` of 6 values is ω at t_ref and its rate of change α (rad/s²) (see
    :meth:`Problem.contrast`); α counts in the pixels its bend moves the window's far end, and
    ``bend_cost`` times their square is taken off the normalized contrast, so that α stays near
    0 where the events do not determine it.
    """
    omega = np.asarray(omega, dtype=np.float64)
    units = _units(problem, len(omega), scale)
    norm, grad = problem.contrast(omega, scale, config.sigma_px, gradient=True)
    if not norm > 0:
        return Refined(omega, norm, None)
    bend = np.r_[np.zeros(3), np.ones(len(omega) - 3)] * bend_cost

    def objective(phi: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = problem.contrast(phi / units, scale, config.sigma_px, gradient=True)
        return value / norm - bend @ phi**2, grad / (norm * units) - 2.0 * bend * phi

    steps = config.iterations if iterations is None else iterations
    x0 = omega * units
    start = (1.0 - bend @ x0**2, grad / (norm * units) - 2.0 * bend * x0)
    found = maximize_bfgs(objective, x0, steps, 0.5, xtol_px, inv_hessian, start)
    value = found.value + bend @ found.x**2
    return Refined(found.x / units, value * norm, found.inv_hessian)


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
            omega = refine(sub, omega, scale, config, xtol_px=config.coarse_xtol_px).omega
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


def estimate_whole(events: EventArray, camera: Intrinsics | None = None) -> np.ndarray:
    """One ω (3,) rad/s from all of ``events`` (none thinned, default settings), standing for
    the whole span: ``spikegyro baseline cmax --whole``. The events are warped to the middle
    of the span (its mean rate is the same at any reference time, and warping to one end moves
    the far end's events a whole span's motion, where sparse events find spurious maxima)."""
    return estimate_window(events, camera, CMaxConfig(max_events=max(len(events), 1)))
