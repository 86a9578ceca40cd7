"""Composed event recordings with known truth, for the one-rotation test (``ill_posed`` bit 4).

Textured objects moved on their own over a still camera's view (silent but for sensor noise)
or a rotating camera's view, built independently of the code under test: each object is a cloud
of random texture points in its own frame, placed at time t by its own 2D motion (a
translation, a turn about its centre, or a side-to-side swing), and each point fires at random
times at the pixel it lands on. A rotating camera sees random world points all around it,
turned by SciPy's rotations. Sensor: 240 x 180 pixels, f = 200 px.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from test_cmax import HEIGHT, WIDTH, F, camera_to_world

from spikegyro.events.core import EventArray

Pose = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""``pose(t)`` -> (x, y, angle): an object's centre (px) and turn (rad) at times t (s)."""


@dataclass(frozen=True)
class Patch:
    """A textured object: ``points`` texture points uniform in a ``width`` x ``height`` px
    rectangle about its centre, posed by ``pose``, each firing ``rate`` times per second."""

    pose: Pose
    width: float
    height: float
    points: int = 400
    rate: float = 100.0


def moving(x0: float, y0: float, vx: float = 0.0, vy: float = 0.0, turn: float = 0.0) -> Pose:
    """A pose from (x0, y0) px moving at (vx, vy) px/s and turning at ``turn`` rad/s."""
    return lambda t: (x0 + vx * t, y0 + vy * t, turn * t)


def swinging(x0: float, y0: float, amplitude: float, hz: float, pivot_px: float = 0.0) -> Pose:
    """A side-to-side swing (a waving hand): centre x = x0 + amplitude sin(2π hz t) px; with
    ``pivot_px`` > 0 it also tilts as if swung from a pivot that far below it."""

    def pose(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dx = amplitude * np.sin(2 * np.pi * hz * t)
        angle = np.arctan2(dx, pivot_px) if pivot_px > 0 else 0 * t
        return x0 + dx, y0 + 0 * t, angle

    return pose


def patch_events(patch: Patch, duration_s: float, rng: np.random.Generator) -> EventArray:
    """The events of ``patch`` over ``duration_s`` (those landing on the sensor)."""
    u = rng.uniform(-0.5, 0.5, (patch.points, 2)) * (patch.width, patch.height)
    per_point = rng.poisson(patch.rate * duration_s, patch.points)
    which = np.repeat(np.arange(patch.points), per_point)
    t = rng.uniform(0.0, duration_s, len(which))
    x0, y0, angle = patch.pose(t)
    c, s = np.cos(angle), np.sin(angle)
    x = np.rint(x0 + c * u[which, 0] - s * u[which, 1])
    y = np.rint(y0 + s * u[which, 0] + c * u[which, 1])
    return _events(x, y, t)


def noise_events(rate_per_px: float, duration_s: float, rng: np.random.Generator) -> EventArray:
    """Background activity: ``rate_per_px`` events per pixel per second, uniform in space."""
    n = rng.poisson(rate_per_px * WIDTH * HEIGHT * duration_s)
    x, y = rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n)
    return _events(x, y, rng.uniform(0.0, duration_s, n))


def rotating_view(
    omega_dps: tuple[float, float, float],
    duration_s: float,
    seed: int,
    world: np.ndarray | None = None,
) -> EventArray:
    """A camera turning at ω (deg/s) amid world points (``world``, (N, 3) directions; default
    8,000 random ones all around it, about 600 in view at a time), each firing 300 times per
    second at random (several times per window, as an edge does): the camera frame's ray of a
    point is R(t)^T b_w with R(t) = exp([ω]x t) (SciPy), projected by the pinhole."""
    rng = np.random.default_rng(seed)
    if world is None:
        world = rng.normal(size=(8000, 3))
    world = world / np.linalg.norm(world, axis=1, keepdims=True)
    fires = rng.poisson(300.0 * duration_s, len(world))
    t = rng.uniform(0.0, duration_s, int(fires.sum()))
    world = np.repeat(world, fires, axis=0)
    ray = camera_to_world(np.radians(omega_dps), None, t, duration_s).inv().apply(world)
    ahead = ray[:, 2] > 0.1
    x = np.rint(F * ray[ahead, 0] / ray[ahead, 2] + WIDTH / 2)
    y = np.rint(F * ray[ahead, 1] / ray[ahead, 2] + HEIGHT / 2)
    return _events(x, y, t[ahead])


def compose(*parts: EventArray) -> EventArray:
    """The events of ``parts`` merged in time order."""
    x, y, t = (np.concatenate([getattr(p, k) for p in parts]) for k in ("x", "y", "t"))
    order = np.argsort(t, kind="stable")
    return EventArray.from_arrays(x[order], y[order], t[order], np.ones(len(t)), WIDTH, HEIGHT)


def _events(x: np.ndarray, y: np.ndarray, t_s: np.ndarray) -> EventArray:
    """Events at pixels (x, y) and times ``t_s`` (s), those off the sensor dropped, in order."""
    ok = (x >= 0) & (x < WIDTH) & (y >= 0) & (y < HEIGHT)
    order = np.argsort(t_s[ok], kind="stable")
    t_us = np.rint(t_s[ok][order] * 1e6)
    return EventArray.from_arrays(
        x[ok][order], y[ok][order], t_us, np.ones(len(t_us)), WIDTH, HEIGHT
    )


def scenes(duration_s: float = 0.4, seed: int = 0) -> dict[str, tuple[EventArray, bool]]:
    """Named composed recordings and whether the camera is still (True) or rotating (False).

    Still camera (a noise floor of 0.05 events/px/s): two textured patches moving each its own
    way; a hand-like blob swinging side to side; a patch turning in place; a single bar
    sweeping across the view after silence (the hard negative: the silence is the evidence).
    Rotating camera: pan, tilt, roll, a slow hand-held-like rate and a fast mixed one over
    points all around; a roll over one long straight edge (a line that never leaves the view).
    """
    rng = np.random.default_rng(seed)

    def noise() -> EventArray:
        return noise_events(0.05, duration_s, rng)

    def blob(pose: Pose, w: float, h: float, points: int = 600) -> EventArray:
        return patch_events(Patch(pose, w, h, points), duration_s, rng)

    # Silence (sensor noise) for 60 % of the time, then a bar as tall as most of the view
    # sweeping at 500 px/s.
    quiet_s = 0.6 * duration_s
    bar = patch_events(Patch(moving(20.0, HEIGHT / 2, vx=500.0), 14, 150, 900),
                       duration_s - quiet_s, rng)  # fmt: skip
    late_bar = EventArray.from_arrays(bar.x, bar.y, bar.t + round(quiet_s * 1e6), bar.p,
                                      WIDTH, HEIGHT)  # fmt: skip
    # One long straight edge across the view (points along it), never out of view as it rolls.
    line = np.column_stack([np.linspace(-0.5, 0.5, 600), np.full(600, 0.1), np.ones(600)])
    return {
        "two patches": (compose(noise(), blob(moving(60, 60, vx=150), 60, 50),
                                blob(moving(170, 120, vy=-120, turn=1.0), 60, 50)), True),
        "swinging hand": (compose(noise(), blob(swinging(80, 100, 25, 2.5, 80), 45, 70)), True),
        "turning patch": (compose(noise(), blob(moving(120, 90, turn=3.0), 80, 80, 900)), True),
        "bar after silence": (compose(noise_events(0.05, duration_s, rng), late_bar), True),
        "pan": (rotating_view((0.0, 60.0, 0.0), duration_s, seed + 1), False),
        "tilt": (rotating_view((-45.0, 0.0, 0.0), duration_s, seed + 2), False),
        "roll": (rotating_view((0.0, 0.0, 90.0), duration_s, seed + 3), False),
        "slow hand-held": (rotating_view((4.0, -6.0, 3.0), duration_s, seed + 4), False),
        "fast mixed": (rotating_view((150.0, -200.0, 250.0), duration_s, seed + 5), False),
        "roll over one line": (rotating_view((0.0, 0.0, 60.0), duration_s, seed + 6, line), False),
    }  # fmt: skip
