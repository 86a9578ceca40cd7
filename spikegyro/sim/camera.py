"""Pinhole camera: intrinsics, per-pixel viewing rays, and the image motion a rotation causes."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from spikegyro.errors import InputError


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels; defaults are the paper's DAVIS240C model.

    Pixel (x, y) (0-based column, row) looks along the camera-frame ray
    ((x − cx) / fx, (y − cy) / fy, 1): x right, y down, z forward.
    """

    width: int = 240
    height: int = 180
    fx: float = 200.0
    fy: float = 200.0
    cx: float = 120.0
    cy: float = 90.0

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise InputError(
                f"camera {self.width}x{self.height}, f=({self.fx}, {self.fy}): size and focal "
                "length must be positive."
            )

    @classmethod
    def scaled(cls, width: int, height: int, fov_of: Camera | None = None) -> Camera:
        """A ``width`` x ``height`` camera with the same field of view as ``fov_of`` (default)."""
        ref = fov_of or cls()
        s = width / ref.width
        return cls(
            width,
            height,
            ref.fx * s,
            ref.fy * height / ref.height,
            ref.cx * s,
            ref.cy * height / ref.height,
        )

    @cached_property
    def rays(self) -> np.ndarray:
        """Unit viewing rays of all pixels, camera frame, shape (3, height * width), row-major."""
        x, y = np.meshgrid(np.arange(self.width), np.arange(self.height))
        d = np.stack(
            [(x - self.cx) / self.fx, (y - self.cy) / self.fy, np.ones(x.shape)], 0
        ).reshape(3, -1)
        return d / np.linalg.norm(d, axis=0)

    @property
    def pixel_angle_rad(self) -> float:
        """Angle subtended by one pixel at the principal point, radians."""
        return 1.0 / max(self.fx, self.fy)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) of camera-frame points (..., 3) with z > 0."""
        p = np.asarray(points, dtype=np.float64)
        return np.stack(
            [self.fx * p[..., 0] / p[..., 2] + self.cx, self.fy * p[..., 1] / p[..., 2] + self.cy],
            -1,
        )

    def flow(self, omega: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Image velocity (..., 2), px/s, at pixels (x, y) for rotation ``omega`` (3,) rad/s.

        A world point fixed in space moves in the camera frame as dp/dt = −ω × p; projecting
        gives the classic rotational flow field (independent of depth).
        """
        wx, wy, wz = np.asarray(omega, dtype=np.float64)
        u = (np.asarray(x, dtype=np.float64) - self.cx) / self.fx
        v = (np.asarray(y, dtype=np.float64) - self.cy) / self.fy
        du = u * v * wx - (1 + u * u) * wy + v * wz
        dv = (1 + v * v) * wx - u * v * wy - u * wz
        return np.stack([self.fx * du, self.fy * dv], -1)

    def max_flow(self, omegas: np.ndarray) -> np.ndarray:
        """Largest image speed over the sensor (px/s) for each ω in ``omegas`` (..., 3) rad/s.

        Evaluated on a 9 x 9 grid that includes the corners, where rotational flow peaks.
        """
        xs, ys = np.meshgrid(np.linspace(0, self.width - 1, 9), np.linspace(0, self.height - 1, 9))
        u = ((xs - self.cx) / self.fx).ravel()
        v = ((ys - self.cy) / self.fy).ravel()
        # Flow is linear in ω: stack the per-axis basis fields (points, 2, 3).
        basis = np.stack(
            [
                np.stack([self.fx * u * v, self.fy * (1 + v * v)], -1),
                np.stack([-self.fx * (1 + u * u), -self.fy * u * v], -1),
                np.stack([self.fx * v, -self.fy * u], -1),
            ],
            -1,
        )
        w = np.asarray(omegas, dtype=np.float64)
        speeds = np.linalg.norm(np.einsum("pij,...j->...pi", basis, w), axis=-1)
        return speeds.max(axis=-1)
