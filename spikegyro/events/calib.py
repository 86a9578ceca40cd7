"""Camera calibration: pinhole intrinsics, radial-tangential distortion, and event reprojection.

A network trained on simulated events sees an ideal pinhole camera (by default 240x180 pixels,
f = 200 px, c = (120, 90)). Events from a real sensor are mapped onto that camera by
undistorting each sensor pixel to its viewing ray and projecting the ray with the model's
pinhole. Since sensor pixels are discrete, the mapping is a per-pixel lookup table computed once.

Conventions: pixel (0, 0) is the centre of the top-left pixel (as in OpenCV and the Event Camera
Dataset); normalised coordinates are ``((u - cx) / fx, (v - cy) / fy)``. The distortion model is
OpenCV's "plumb bob" (radial-tangential), with coefficients (k1, k2, p1, p2, k3):

    r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.core import EventArray

DEFAULT_WIDTH, DEFAULT_HEIGHT = 240, 180
DEFAULT_FOCAL_PX = 200.0


@dataclass(frozen=True)
class PinholeCamera:
    """An ideal pinhole camera: image size (pixels) and intrinsics (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def default(cls, scale: float = 1.0) -> PinholeCamera:
        """The simulator's camera (240x180, f = 200 px, c = (120, 90)) resized by ``scale``."""
        return cls(
            DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FOCAL_PX, DEFAULT_FOCAL_PX, 120.0, 90.0
        ).scaled(scale)

    def scaled(self, factor: float) -> PinholeCamera:
        """The same field of view on an image ``factor`` times the size.

        Pixel centres sit at integer coordinates, so the principal point maps as
        ``(c + 0.5) * factor - 0.5``.
        """
        if factor == 1.0:
            return self
        return PinholeCamera(
            width=max(1, round(self.width * factor)),
            height=max(1, round(self.height * factor)),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
        )

    def project(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised image coordinates -> pixel coordinates (floats)."""
        return self.fx * np.asarray(xn) + self.cx, self.fy * np.asarray(yn) + self.cy


@dataclass(frozen=True)
class Calibration:
    """Intrinsics of a real sensor plus radial-tangential distortion (k1, k2, p1, p2, k3).

    The sensor size is not part of a calibration file; it comes from the events being mapped.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @property
    def is_pinhole(self) -> bool:
        """True when there is no distortion."""
        return self.k1 == self.k2 == self.p1 == self.p2 == self.k3 == 0.0

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalised coordinates -> distorted normalised coordinates."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def undistort(
        self, xd: np.ndarray, yd: np.ndarray, *, iterations: int = 20, tol: float = 1e-12
    ) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` by Newton's method (analytic 2x2 Jacobian).

        Converges quadratically for the distortions of real lenses; points where the model
        folds over (no inverse within ``iterations``) come back as NaN.
        """
        xd, yd = np.asarray(xd, dtype=np.float64), np.asarray(yd, dtype=np.float64)
        x, y = xd.copy(), yd.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        for _ in range(iterations):
            fx, fy = self.distort(x, y)
            ex, ey = fx - xd, fy - yd
            if np.all(np.abs(ex) + np.abs(ey) < tol):
                break
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
            jxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
            jyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
            jxy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            det = jxx * jyy - jxy * jxy
            x = x - (jyy * ex - jxy * ey) / det
            y = y - (jxx * ey - jxy * ex) / det
        fx, fy = self.distort(x, y)
        bad = ~(np.abs(fx - xd) + np.abs(fy - yd) < 1e-9)
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)

    def pixel_rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor pixel coordinates -> undistorted normalised coordinates (ray x/z, y/z)."""
        xd = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        yd = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        return (xd, yd) if self.is_pinhole else self.undistort(xd, yd)

    def lookup_table(self, width: int, height: int, target: PinholeCamera) -> np.ndarray:
        """For each pixel of a ``width`` x ``height`` sensor, its flat index in ``target``.

        Returns an int32 array of shape (height, width): ``y' * target.width + x'`` of the nearest
        target pixel, or -1 where the ray falls outside the target image.
        """
        return _lookup_table(self, int(width), int(height), target)

    def map_events(self, events: EventArray, target: PinholeCamera) -> EventArray:
        """Reproject events onto ``target``'s pixel grid, dropping those that fall outside it."""
        lut = self.lookup_table(events.width, events.height, target)
        idx = lut[events.y.astype(np.intp), events.x.astype(np.intp)]
        keep = idx >= 0
        idx = idx[keep]
        return replace(
            events[keep],
            x=(idx % target.width).astype(np.int16),
            y=(idx // target.width).astype(np.int16),
            width=target.width,
            height=target.height,
        )


@functools.lru_cache(maxsize=8)
def _lookup_table(calib: Calibration, width: int, height: int, target: PinholeCamera) -> np.ndarray:
    v, u = np.mgrid[0:height, 0:width]
    xn, yn = calib.pixel_rays(u, v)
    tu, tv = target.project(xn, yn)
    with np.errstate(invalid="ignore"):
        iu, iv = np.rint(tu), np.rint(tv)
        inside = (iu >= 0) & (iu < target.width) & (iv >= 0) & (iv < target.height)
    lut = np.full((height, width), -1, dtype=np.int32)
    lut[inside] = (iv[inside] * target.width + iu[inside]).astype(np.int32)
    lut.flags.writeable = False
    return lut


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration text file.

    Accepts the Event Camera Dataset's ``calib.txt`` (one line ``fx fy cx cy k1 k2 p1 p2 k3``),
    the same without ``k3`` (8 numbers), or plain intrinsics ``fx fy cx cy`` (4 numbers).
    Numbers may be spread over several lines; ``#`` starts a comment.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such calibration file.")
    words = []
    for line in path.read_text(errors="replace").splitlines():
        words += line.split("#", 1)[0].replace(",", " ").split()
    try:
        values = [float(w) for w in words]
    except ValueError:
        raise InputError(
            f"{path}: a calibration file must hold numbers only: 'fx fy cx cy [k1 k2 p1 p2 [k3]]'."
        ) from None
    if len(values) not in (4, 8, 9):
        raise InputError(
            f"{path}: {len(values)} numbers; expected 'fx fy cx cy k1 k2 p1 p2 k3' (the Event "
            "Camera Dataset's calib.txt), 8 without k3, or 4 for a pinhole."
        )
    return _checked(Calibration(*values), str(path))


def _checked(calib: Calibration, source: str) -> Calibration:
    values = (calib.fx, calib.fy, calib.cx, calib.cy)
    if not all(math.isfinite(v) for v in values) or calib.fx <= 0 or calib.fy <= 0:
        raise InputError(
            f"{source}: focal lengths must be positive and finite, got fx {calib.fx}, fy "
            f"{calib.fy}; give the sensor's fx fy cx cy in pixels."
        )
    return calib


def resolve_calibration(
    events: str | os.PathLike,
    calib: str | os.PathLike | None = None,
    intrinsics: tuple[float, float, float, float] | None = None,
) -> tuple[Calibration | None, Path | None]:
    """The sensor calibration the command-line options ask for, as (calibration, file read).

    ``--calib FILE`` and ``--intrinsics fx fy cx cy`` exclude each other; with neither, an Event
    Camera Dataset folder's own ``calib.txt`` is used; otherwise (None, None): the events are
    taken as already on the model's pinhole.
    """
    if calib is not None and intrinsics is not None:
        raise InputError("--calib and --intrinsics: give one of them, not both.")
    if intrinsics is not None:
        return _checked(
            Calibration(*intrinsics), f"--intrinsics {' '.join(map(str, intrinsics))}"
        ), None
    if calib is None and (Path(events) / "calib.txt").is_file():
        calib = Path(events) / "calib.txt"
    if calib is None:
        return None, None
    return load_calibration(calib), Path(calib)
