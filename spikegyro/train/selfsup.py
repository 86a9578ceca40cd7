"""A training signal from real events without a gyro: the contrast of events warped by ω(t).

Under a pure rotation, the events of a short interval warped to its end along the rotation's
flow stack onto the scene's edges; the image of warped events (IWE) is sharpest at the true ω.
For a window whose network output is ω(t) at every millisecond, each *reference step* k (every
``every_ms`` from ``from_step`` on, where the network has settled) takes the events of the
``span_ms`` before the end of bin k, warps them to that instant with the constant rotation
ω(t_k) through the camera's calibration (undistorted rays, exact SO(3) warp), and scores the
blurred IWE's variance relative to the unwarped one's: the *contrast gain* G(ω) = C(ω) / C(0).

Why the variance, normalised per sub-window: the variance is the objective the project's
contrast maximization (:mod:`spikegyro.cmax`) maximizes with an exact gradient, so the loss and
the estimator users already trust agree on what "sharp" means; dividing by C(0), a constant of
the data, makes sub-windows with many and with few events weigh alike (a gain is unit-free).
The loss is ``1 - G`` averaged over the reference steps: 0 for ω = 0, negative when ω sharpens.

Collapse: events warped off the image cast no votes, which lowers C, so flinging events away
never pays; the rotation model has no degree of freedom that squeezes events onto a point or a
line (a flow network's does). What a rotation cannot explain is guarded by the teacher:
:func:`teacher_series` runs contrast maximization on each sub-window and its best gain says
how much one rotation explains; sub-windows below ``min_gain`` (textureless, aperture-bound,
or a moving scene) carry no loss.

The ``teacher`` variant uses those estimates as pseudo-labels under the paper's Euclidean loss.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.problem import Intrinsics, Problem, make_problem
from spikegyro.cmax.search import search
from spikegyro.cmax.windows import pixel_speed, rms_radius
from spikegyro.events.core import EventArray

LOSSES = ("contrast", "teacher")


@dataclass(frozen=True)
class ContrastLossConfig:
    """Where and how a window's ω(t) is scored by event contrast.

    Attributes:
        span_ms: events of at least this many milliseconds before each reference time are
            warped ...
        max_span_ms: ... and at most this many: within these bounds, long enough that the
            teacher's rotation moves edges ``target_px`` (slow motion needs long spans: at
            5 deg/s and f = 245 px edges move a pixel every 47 ms). Spans may reach before the
            window's start: the loss reads the recording, not the window.
        target_px: typical edge displacement over a span, pixels.
        every_ms: a reference step every this many milliseconds ...
        from_step: ... from this step (ms) of the window on, where the network has settled.
        sigma_px: Gaussian blur of the IWE, pixels.
        max_events: a sub-window's events are thinned at random to at most this many (cost).
        min_events: sub-windows with fewer events carry no loss.
        min_gain: sub-windows whose best single rotation (the teacher's) sharpens the image by
            less than this factor over ω = 0 carry no loss.
    """

    span_ms: float = 40.0
    max_span_ms: float = 200.0
    target_px: float = 4.0
    every_ms: int = 10
    from_step: int = 50
    sigma_px: float = 1.0
    max_events: int = 4000
    min_events: int = 300
    min_gain: float = 1.05

    def steps(self, num_steps: int) -> list[int]:
        """Reference steps k of a ``num_steps`` window: the bins ending on a multiple of
        ``every_ms`` from ``from_step`` on (k = 59, 69, ..., 99 for 100 ms by default)."""
        return [k for k in range(self.from_step, num_steps) if (k + 1) % self.every_ms == 0]


@dataclass(frozen=True)
class SubWindow:
    """One reference step of a window: its events as rays, their contrast at ω = 0, the
    teacher's estimate (rad/s) and gain, and the factor (3,) from the network's output at the
    step to rad/s: 1 ms over the step's length on the event clock (1 on the paper's), times the
    focal-length gain of a network reading the sensor's own pixels (tilt and pan f_model / f)."""

    step: int
    problem: Problem
    c0: float
    teacher: np.ndarray
    teacher_gain: float
    rate: np.ndarray = field(default_factory=lambda: np.ones(3))


def sub_problem(
    events: EventArray,
    t_ref_us: int,
    camera: Intrinsics,
    config: ContrastLossConfig,
    rng: np.random.Generator,
    span_us: int | None = None,
) -> Problem | None:
    """The events of ``span_us`` (default ``span_ms``) before ``t_ref_us`` (µs) as a warping
    problem with times to ``t_ref_us``; None when fewer than ``min_events`` remain (hot pixels
    dropped)."""
    span_us = int(config.span_ms * 1000) if span_us is None else span_us
    part = events.slice_time(int(t_ref_us - span_us), int(t_ref_us))
    if len(part) < config.min_events:
        return None
    cmax = CMaxConfig(max_events=config.max_events)
    problem = make_problem(part, camera, cmax, rng, t_ref_us=float(t_ref_us))
    return problem if len(problem) >= config.min_events else None


def contrast_gain(problem: Problem, omega: np.ndarray, sigma_px: float) -> float:
    """C(ω) / C(0) of a problem's blurred IWE (1 where the IWE is flat)."""
    c0 = problem.contrast(np.zeros(3), 1, sigma_px)[0]
    return problem.contrast(np.asarray(omega, dtype=np.float64), 1, sigma_px)[0] / max(c0, 1e-300)


class _LossOfGain(torch.autograd.Function):
    """1 − C(ω)/C(0) of one sub-window, with the objective's exact gradient wrt ω (3,) rad/s."""

    @staticmethod
    def forward(ctx, omega: torch.Tensor, problem: Problem, c0: float, sigma_px: float):
        value, gradient = problem.contrast(
            omega.detach().double().cpu().numpy(), 1, sigma_px, gradient=True
        )
        ctx.save_for_backward(torch.from_numpy(-gradient / c0).to(omega))
        return omega.new_tensor(1.0 - value / c0)

    @staticmethod
    def backward(ctx, grad_output: torch.Tensor):
        (gradient,) = ctx.saved_tensors
        return grad_output * gradient, None, None, None


def gain_loss(omega: torch.Tensor, sub: SubWindow, sigma_px: float) -> torch.Tensor:
    """1 − G(ω) of one sub-window for ω (3,) rad/s, differentiable (see the module docstring)."""
    return _LossOfGain.apply(omega, sub.problem, sub.c0, sigma_px)


def window_loss(
    omega: torch.Tensor, subs: list[SubWindow], config: ContrastLossConfig, kind: str
) -> torch.Tensor | None:
    """A window's self-supervised loss from its output ω (3, T) rad/s; None when none of its
    sub-windows passes the teacher's gain test.

    ``kind``: "contrast" (1 − G averaged over the sub-windows) or "teacher" (the mean Euclidean
    distance, rad/s, to the teacher's estimates).
    """
    used = [s for s in subs if s.teacher_gain >= config.min_gain]
    if not used:
        return None
    if kind == "teacher":
        target = torch.from_numpy(np.stack([s.teacher for s in used])).to(omega)
        steps = torch.tensor([s.step for s in used])
        rates = torch.from_numpy(np.stack([s.rate for s in used])).to(omega)
        return (omega[:, steps].T * rates - target).pow(2).sum(dim=1).sqrt().mean()
    terms = [
        gain_loss(omega[:, s.step] * torch.from_numpy(s.rate).to(omega), s, config.sigma_px)
        for s in used
    ]
    return torch.stack(terms).mean()


@dataclass(frozen=True)
class TeacherSeries:
    """Contrast maximization's estimate on the sub-window ending at each of ``t_us`` (µs, a
    regular grid): ω (n, 3) rad/s, its contrast gain (n,) (NaN where too few events) and the
    sub-window's span (n,) µs."""

    t_us: np.ndarray
    omega: np.ndarray
    gain: np.ndarray
    span_us: np.ndarray

    def index(self, t_ref_us: int) -> int:
        """The grid time nearest ``t_ref_us``."""
        i = int(np.clip(np.searchsorted(self.t_us, t_ref_us), 0, len(self.t_us) - 1))
        if i > 0 and t_ref_us - self.t_us[i - 1] < self.t_us[i] - t_ref_us:
            i -= 1
        return i


def teacher_series(
    events: EventArray,
    camera: Intrinsics,
    config: ContrastLossConfig,
    grid_us: int,
    *,
    search_every: int = 100,
    progress: Callable[[int], None] | None = None,
) -> TeacherSeries:
    """Contrast maximization over a whole recording, one estimate per ``grid_us`` (µs) from
    ``span_ms`` after its first event: each estimate refines the previous one (tracking, about
    25 ms of CPU), with a global grid search at the first and every ``search_every``-th, so a
    lost track is found again; each span follows the previous estimate's image speed (see
    :class:`ContrastLossConfig`). ``progress(k)`` is called after each estimate."""
    times = np.arange(int(events.t[0] + config.span_ms * 1000), int(events.t[-1]) + 1, grid_us)
    omega = np.zeros((len(times), 3))
    gain = np.full(len(times), np.nan)
    spans = np.full(len(times), int(config.span_ms * 1000))
    cmax = CMaxConfig(max_events=config.max_events)
    radius = rms_radius(events.width, events.height, camera.cx, camera.cy)
    previous: np.ndarray | None = None
    for k, t_ref in enumerate(times):
        rng = np.random.default_rng([k, 11])
        if previous is not None:
            speed = pixel_speed(previous, camera.fx, radius)
            span_s = config.target_px / max(speed, 1e-9)
            spans[k] = int(1000 * np.clip(1000 * span_s, config.span_ms, config.max_span_ms))
        problem = sub_problem(events, int(t_ref), camera, config, rng, int(spans[k]))
        if problem is not None:
            fresh = previous is None or k % search_every == 0
            omega[k] = search(problem, cmax, init=previous, grid=fresh, rng=rng).omega
            gain[k] = contrast_gain(problem, omega[k], config.sigma_px)
            previous = omega[k]
        if progress is not None:
            progress(k + 1)
    return TeacherSeries(times.astype(np.int64), omega.astype(np.float32), gain, spans)


def scored_sub_window(
    events: EventArray,
    t_ref_us: int,
    step: int,
    camera: Intrinsics,
    teacher: TeacherSeries,
    config: ContrastLossConfig,
    rate: np.ndarray | None = None,
) -> SubWindow | None:
    """The sub-window of ``events`` ending at ``t_ref_us`` (µs) with the teacher's estimate;
    None when it has too few events or a flat image. ``rate``: see :class:`SubWindow`."""
    i = teacher.index(t_ref_us)
    rng = np.random.default_rng([t_ref_us, 5])
    problem = sub_problem(events, t_ref_us, camera, config, rng, int(teacher.span_us[i]))
    if problem is None:
        return None
    c0 = problem.contrast(np.zeros(3), 1, config.sigma_px)[0]
    if not c0 > 0:
        return None
    rate = np.ones(3) if rate is None else np.asarray(rate, np.float64)
    return SubWindow(step, problem, float(c0), teacher.omega[i], float(teacher.gain[i]), rate)


def gain_of_prediction(omega: np.ndarray, subs: list[SubWindow], sigma_px: float) -> float:
    """Mean contrast gain G of per-step estimates ``omega`` (T, 3) rad/s over ``subs``
    (NaN without any): the validation score on real windows (1 = no better than ω = 0)."""
    gains = [
        sub.problem.contrast(omega[sub.step].astype(np.float64) * sub.rate, 1, sigma_px)[0]
        / sub.c0
        for sub in subs
    ]
    return float(np.mean(gains)) if gains else math.nan


def batch_loss(
    omega: torch.Tensor, subs: list[list[SubWindow]], config: ContrastLossConfig, kind: str
) -> torch.Tensor:
    """Mean self-supervised loss of a batch of real windows' outputs ω (n, 3, T) rad/s, over the
    windows that carry one (zero, still attached to the graph, when none does)."""
    losses = [window_loss(omega[i], s, config, kind) for i, s in enumerate(subs)]
    kept = [loss for loss in losses if loss is not None]
    return torch.stack(kept).mean() if kept else omega.sum() * 0.0
