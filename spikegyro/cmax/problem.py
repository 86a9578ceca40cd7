"""One window of events made ready for warping: rays, times to the reference time, intrinsics.

Events are undistorted to rays per sensor pixel with the sensor's calibration
(``spikegyro.events.calib.Calibration``; a plain pinhole when it has no distortion), in floating
point: no rounding onto a pixel grid and no event lost where the undistorted image overhangs the
sensor. Hot pixels are dropped (:mod:`spikegyro.cmax.windows`): they pull the estimate to 0.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from spikegyro.cmax import iwe
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.windows import hot_pixel_mask
from spikegyro.events.calib import DEFAULT_FOCAL_PX, DEFAULT_WIDTH, PinholeCamera
from spikegyro.events.core import EventArray


class Intrinsics(Protocol):
    """Pinhole intrinsics in pixels (``PinholeCamera``, ``Calibration``, ``spikegyro.sim.Camera``).

    An object that also has ``pixel_rays(u, v)`` (a ``Calibration``) undistorts with it.
    """

    fx: float
    fy: float
    cx: float
    cy: float


def base_scale(width: int, height: int, max_pixels: int) -> int:
    """The smallest whole binning factor ``s`` that leaves a ``width`` x ``height`` image at most
    ``max_pixels`` pixels, ``ceil(width / s) * ceil(height / s)`` (1 when ``max_pixels <= 0``).

    The objective's cost is mostly its image (two blurs and a variance per evaluation), so a
    megapixel sensor's events are voted into an image binned to about a DAVIS240's size: the
    contrast peak then has the same shape in binned pixels whatever the sensor.
    """
    s = 1
    while max_pixels > 0 and math.ceil(width / s) * math.ceil(height / s) > max_pixels:
        s += 1
    return s


@dataclass(frozen=True)
class Problem:
    """One window ready for warping: rays, times to t_ref, and the pinhole to project with;
    ``base``: the binning of the image at pyramid scale 1 (:func:`base_scale`)."""

    bx: np.ndarray  # (N,) ray x/z
    by: np.ndarray  # (N,) ray y/z
    dt: np.ndarray  # (N,) t_ref - t, seconds
    weights: np.ndarray  # (N,) votes
    intrinsics: np.ndarray  # fx, fy, cx, cy
    width: int
    height: int
    base: int = 1

    def level(self, scale: int) -> int:
        """The image's downscale factor from the sensor's pixels at pyramid ``scale``."""
        return scale * self.base

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
        """Image displacement (sensor px) that 1 rad/s causes at the window's ends: ω's natural
        scale."""
        half_span = float(np.abs(self.dt).max()) if len(self) else 0.0
        return max(half_span, 1e-4) * float(self.intrinsics[0])

    def in_view(self, omega: np.ndarray, scale: int) -> np.ndarray:
        """Whether each event, warped by ``omega`` (rad/s), lands on the image at pyramid
        ``scale`` (N,) bool."""
        level = self.level(scale)
        width, height = math.ceil(self.width / level), math.ceil(self.height / level)
        params = np.asarray(omega, dtype=np.float64)
        u, v, valid, _, _ = iwe.warp(
            self.bx, self.by, self.dt, params, self.intrinsics, float(level), False
        )
        return valid & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)

    def contrast(
        self, omega: np.ndarray, scale: int, sigma: float, gradient: bool = False
    ) -> tuple[float, np.ndarray]:
        """IWE variance at pyramid ``scale`` (and its gradient in 1/(rad/s)).

        ``omega``: (3,) rad/s, a constant rotation; or (6,), ω at t_ref (rad/s) and its rate of
        change α (rad/s²) (:func:`~spikegyro.cmax.iwe.warp`; the gradient is
        then wrt both).
        """
        level = self.level(scale)
        return iwe.contrast(
            self.bx,
            self.by,
            self.dt,
            self.weights,
            np.asarray(omega, dtype=np.float64),
            self.intrinsics,
            float(level),
            math.ceil(self.width / level),
            math.ceil(self.height / level),
            iwe.gaussian_taps(sigma),
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


def camera_rays(camera: Intrinsics, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ray_table` of ``camera``, cached by value: a calibration undistorts, any other
    intrinsics are a plain pinhole."""
    key = camera if hasattr(camera, "pixel_rays") else (camera.fx, camera.fy, camera.cx, camera.cy)
    return ray_table(key, width, height)


def event_rays(
    events: EventArray, camera: Intrinsics, hot_pixel_factor: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(keep, bx, by)``: which events are usable (not on a hot pixel, with a defined ray) and
    every event's ray x/z and y/z."""
    keep = hot_pixel_mask(events.x, events.y, events.width, events.height, hot_pixel_factor)
    xs, ys = camera_rays(camera, events.width, events.height)
    ix, iy = events.x.astype(np.intp), events.y.astype(np.intp)
    bx, by = xs[iy, ix], ys[iy, ix]
    return keep & np.isfinite(bx) & np.isfinite(by), bx, by


def dither(
    bx: np.ndarray, by: np.ndarray, fx: float, fy: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Rays ``bx, by`` (x/z, y/z) each moved uniformly within its pixel (focal lengths ``fx``,
    ``fy`` px): events on pixel centres stack up exactly under ω = 0, which gives the contrast
    a spurious peak there that pulls a sparse window's estimate towards 0."""
    jitter = rng.random((len(bx), 2)) - 0.5
    return bx + jitter[:, 0] / fx, by + jitter[:, 1] / fy


def make_problem(
    events: EventArray,
    camera: Intrinsics,
    config: CMaxConfig,
    rng: np.random.Generator,
    t_ref_us: float | None = None,
) -> Problem:
    """Rays of ``events`` (hot pixels dropped, subsampled to ``max_events``, :func:`dither`-ed)
    around ``t_ref_us``.

    ``t_ref_us`` defaults to the middle of the events' span.
    """
    keep, bx, by = event_rays(events, camera, config.hot_pixel_factor)
    index = np.flatnonzero(keep)
    if len(index) > config.max_events:
        index = np.sort(rng.choice(index, config.max_events, replace=False))
    # Its own generator, as the engines' (the subsampling's draws stay as they were).
    jitter = np.random.default_rng(config.seed + 1)
    bx, by = dither(bx[index], by[index], camera.fx, camera.fy, jitter)
    t = events.t.astype(np.float64)
    t_ref = 0.5 * (t[0] + t[-1]) if t_ref_us is None else float(t_ref_us)
    intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy], dtype=np.float64)
    return Problem(
        bx,
        by,
        (t_ref - t[index]) * 1e-6,
        np.ones(len(index)),
        intrinsics,
        events.width,
        events.height,
        base_scale(events.width, events.height, config.max_pixels),
    )
