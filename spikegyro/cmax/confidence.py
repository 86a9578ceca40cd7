"""Does one rotation explain a window's events? The test behind ``ill_posed`` bit 4.

Contrast maximization always returns the ω that sharpens the events best, also where the scene
itself moves (a static camera watching people walk) or where two parts of the image move
differently. A camera's own rotation moves every textured part of the view, and every part the
way ω says. The test asks four questions of a window and its estimate ω; any "no" is bit 4.

1. Does ω sharpen the window, and each half of it, more than the reverse rotation -ω does?
   The halves split the events at their median ray x (left, right) and at their median ray y
   (top, bottom); the ratio is the contrast at ω over that at -ω. Where events do not move
   with ω (a still object's flicker, sensor noise, a part of the scene that moves otherwise),
   ω and -ω move them by the same distance in opposite directions and blur them alike (over
   the events that both leave in view, so that the image's border favours neither, and on a
   window warped to its middle: warped to one end, one of them moves the oldest events twice
   as far, outward where perspective stretches them): the
   ratio's null is 1 whatever the texture, the event count or the image scale, where a gain
   over ω = 0 has no such null (ω = 0 leaves votes where they fell). Under a rotation, ω
   undoes the blur that -ω doubles: 1.05 to 2 for halves of real and simulated rotations on
   the coarser image the halves are judged on, 1.25 to 3 for whole windows. Ratios under
   ``min_reversal`` (1.05) say no; so does a whole window that ω sharpens by less than
   ``min_gain`` over ω = 0.
2. Does each half agree with ω? Each half's own best ω (refined from the window's ω or from 0,
   whichever sharpens it more, on a coarser image) is compared with the window's:
   ``agreement(A) = C_A(ω) / C_A(ω_A)`` must reach ``min_agreement`` in every half that its own
   rotation sharpens by ``min_gain`` (two rotations, one per half, leave one half well below its
   own best). Halves' own estimates are not compared with each other: from half an image, roll
   trades off against tilt or pan, so they scatter along that direction even under one rotation.
3. Are the events spread over the view, or one compact object? The core of the events (the
   ``core`` share nearest their median) spans an ellipse (:func:`spread`); one covering less
   than ``max_area`` of the view and not a line (narrower than ``min_width`` of its length)
   is one object moving before a still camera: a rotation lights up the textured view beyond
   one blob. A line is exempt: one straight edge looks the same whether it moves or the camera
   pans past it, and rotating cameras often see one long edge.
4. Did something enter a quiet view? Within ``quiet_ms`` after the view was quiet (too few
   events for a well-posed window), events covering less than ``max_area`` of the view, a line
   included, are an object entering a still camera's view (a bar swept across it): a rotating
   camera had shown something before. Only the live engine remembers the quiet view.

A weak sharpening (question 1) of an estimate that moves edges by only a few pixels over its
window (a stream's first windows, a slow pan) is another matter: so little motion blurs little
under any rotation, and :func:`rotation_flags` says that the motion is too little to tell from
none (``ill_posed`` bit 2) rather than that one rotation does not explain it (bit 4). What the
test cannot tell apart: a rotating camera whose view holds one compact textured object and
nothing else (it reads as an object before a still camera), and a lone edge sweeping a view
that was never quiet (it reads as a pan).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from spikegyro.cmax.config import CMaxConfig, OneRotationTest
from spikegyro.cmax.problem import Intrinsics, Problem, default_camera, make_problem
from spikegyro.cmax.search import refine
from spikegyro.events.core import EventArray
from spikegyro.stream.estimator import ILL_LITTLE_MOTION, ILL_NOT_ONE_ROTATION


@dataclass(frozen=True)
class Agreement:
    """What :func:`rotation_agreement` found.

    Attributes:
        agreement: the lowest agreement over the judged halves (NaN: none judged).
        gain: the whole window's contrast at ω over that at ω = 0.
        reversal: the whole window's contrast at ω over that at -ω (see the module).
        half_reversal: the lowest such ratio of a half with enough events (NaN: none).
        judged: how many halves were judged (0 to 4).
        area: the share of the view that the events' core spreads over (:func:`spread`).
        width: the core's width over its length (:func:`spread`).
        compact: whether the core is one compact object (small ``area``, not a line).
        explains: the verdict: whether one rotation explains the events.
    """

    agreement: float
    gain: float
    reversal: float
    half_reversal: float
    judged: int
    area: float
    width: float
    compact: bool
    explains: bool


def spread(problem: Problem, core: float = 0.9) -> tuple[float, float]:
    """How far a window's events spread over the view: ``(area, width)``.

    The core of the events, the ``core`` share of them nearest their median pixel (the rest:
    sensor noise scattered over the view), is summarized by the covariance of its pixel
    positions (rays projected with the pinhole). ``area``: the square root of its determinant
    (px²) over that of events spread evenly over the sensor (``width * height / 12``): about
    the share of the view that a blob covers, 0.87 for a view lit evenly (the core leaves out
    its far corners). ``width``: the covariance ellipse's minor axis over its major axis (1:
    round; near 0: a line). NaN for fewer than 3 events.
    """
    if len(problem) < 3:
        return math.nan, math.nan
    fx, fy, cx, cy = problem.intrinsics
    u, v = fx * problem.bx + cx, fy * problem.by + cy
    far = np.hypot(u - np.median(u), v - np.median(v))
    near = far <= np.quantile(far, core)
    small, large = np.linalg.eigvalsh(np.cov(u[near], v[near]))
    small = max(float(small), 0.0)
    even = problem.width * problem.height / 12.0  # sqrt(det) of an even spread over the sensor
    width = math.sqrt(small / large) if large > 0 else math.nan
    return math.sqrt(small * large) / even, width


def _halves(problem: Problem) -> list[tuple[Problem, Problem]]:
    """The two splits of ``problem``'s events at the median ray x and at the median ray y."""
    splits = []
    for coord in (problem.bx, problem.by):
        below = coord < np.median(coord)
        splits.append((_select(problem, below), _select(problem, ~below)))
    return splits


def _select(problem: Problem, mask: np.ndarray) -> Problem:
    """The events of ``problem`` where ``mask`` holds."""
    p = problem
    return replace(p, bx=p.bx[mask], by=p.by[mask], dt=p.dt[mask], weights=p.weights[mask])


def _ratio(a: float, b: float) -> float:
    """a / b, NaN where b is not positive (no votes left in the image)."""
    return a / b if b > 0 else math.nan


def _reversal(problem: Problem, omega: np.ndarray, scale: int, sigma: float) -> float:
    """Contrast at ω over that at -ω (rad/s) of the events that both leave in view. Events
    that one of them warps off the image would count for the other only: near the image's
    border the ratio would then depend on which way the events are warped, not on how
    sharply (warped to a window's end, -ω pushes twice as many out as ω)."""
    both = problem.in_view(omega, scale) & problem.in_view(-omega, scale)
    kept = replace(problem, weights=problem.weights * both)
    return _ratio(kept.contrast(omega, scale, sigma)[0], kept.contrast(-omega, scale, sigma)[0])


def _judge(
    a: Problem, b: Problem, omega: np.ndarray, config: CMaxConfig, test: OneRotationTest
) -> list[tuple[float, float]]:
    """``(agreement, reversal)`` of halves ``a`` and ``b`` with enough events; the agreement
    NaN where the half shows no structure that its own rotation sharpens."""
    sigma, scale = config.sigma_px, test.scale
    out = []
    for half in (a, b):
        zero = half.contrast(np.zeros(3), scale, sigma)[0]
        if len(half) < test.min_events or not zero > 0:
            continue
        at_omega = half.contrast(omega, scale, sigma)[0]
        reversal = _reversal(half, omega, scale, sigma)
        # Refined from ω or from 0, whichever sharpens the half more: a half that another
        # rotation moves may lie beyond ω's basin.
        start = omega if at_omega >= zero else 0 * omega
        best = refine(half, start, scale, config, test.iterations).contrast
        agreement = at_omega / best if best >= test.min_gain * zero else math.nan
        out.append((agreement, reversal))
    return out


def rotation_agreement(
    problem: Problem,
    omega: np.ndarray,
    config: CMaxConfig | None = None,
    test: OneRotationTest | None = None,
    rng: np.random.Generator | None = None,
) -> Agreement:
    """How well one rotation ω (3,) rad/s explains ``problem``'s events (see the module)."""
    config = config or CMaxConfig()
    test = test or config.one_rotation
    rng = rng or np.random.default_rng(config.seed)
    omega = np.asarray(omega, dtype=np.float64)
    sub = problem.subset(2 * test.max_events, rng)
    sigma = config.sigma_px
    at_omega = sub.contrast(omega, 1, sigma)[0]
    gain = _ratio(at_omega, sub.contrast(np.zeros(3), 1, sigma)[0])
    reversal = _reversal(sub, omega, 1, sigma)
    halves = [v for a, b in _halves(sub) for v in _judge(a, b, omega, config, test)]
    agreements = [a for a, _ in halves if math.isfinite(a)]
    worst = min(agreements, default=math.nan)
    half_reversal = min((r for _, r in halves), default=math.nan)
    area, width = spread(sub, test.core)
    # One blob, not a line: an object before a still camera (a rotation lights up the view).
    compact = area < test.max_area and width >= test.min_width
    explains = (
        not worst < test.min_agreement
        and not compact
        and not gain < test.min_gain
        and not reversal < test.min_reversal
        and not half_reversal < test.min_reversal
    )
    return Agreement(
        worst, gain, reversal, half_reversal, len(agreements), area, width, compact, explains
    )


def one_rotation_explains(
    events: EventArray,
    omega: np.ndarray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    test: OneRotationTest | None = None,
    t_ref_us: float | None = None,
) -> bool:
    """Whether one rotation, ω (3,) rad/s, explains a window of ``events`` (see the module).

    Args:
        events: the window's events, on the sensor's pixels (hot pixels are dropped).
        omega: the rotation to test, e.g. the window's contrast-maximization estimate.
        camera: the sensor's intrinsics or ``Calibration``; default the simulator's pinhole.
        config: estimator settings (blur, hot pixels); default :class:`CMaxConfig`.
        test: the test's thresholds; default ``config.one_rotation``.
        t_ref_us: the time ω stands for, µs (default: the middle of the events).

    Returns:
        False where the halves of the image disagree on the rotation, or the events show no
        structure that a rotation sharpens.
    """
    config = config or CMaxConfig()
    camera = camera or default_camera(events.width, events.height)
    if len(events) < 2:
        return False
    rng = np.random.default_rng(config.seed)
    problem = make_problem(events, camera, config, rng, t_ref_us)
    return rotation_agreement(problem, omega, config, test, rng).explains


def rotation_flags(
    problem: Problem,
    omega: np.ndarray,
    moved_px: float,
    config: CMaxConfig,
    rng: np.random.Generator | None = None,
    after_quiet: bool = False,
) -> int:
    """The ``ill_posed`` bits that the test gives an estimate ω (3,) rad/s of ``problem``
    which moves edges by ``moved_px`` (binned px) over its window: bit 4 where the halves
    disagree, where the events are one compact object (or, ``after_quiet``, when the view was
    quiet a moment ago, one object of any shape, a line included), or where ω sharpens the
    window or a half of it hardly more than -ω does; but bit 2 instead for that last reason
    alone where ω moves edges less than ``judge_px`` (so little motion blurs little either way:
    too little to tell from none). 0 below ``min_motion_px``: bit 2 says so already."""
    test = config.one_rotation
    if test is None or moved_px < config.min_motion_px:
        return 0
    found = rotation_agreement(problem, omega, config, test, rng)
    # A lone object, a line included, lighting up a view that was quiet a moment ago: a still
    # camera's view that something entered (a rotating camera had shown something before).
    entered = after_quiet and found.area < test.max_area
    if found.explains and not entered:
        return 0
    if found.agreement < test.min_agreement or found.compact or entered:
        return ILL_NOT_ONE_ROTATION
    return ILL_NOT_ONE_ROTATION if moved_px >= test.judge_px else ILL_LITTLE_MOTION
