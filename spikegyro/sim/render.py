"""Rendering a pinhole view of an equirectangular panorama for a camera rotation.

Each pixel's unit ray (precomputed once per camera) is rotated into the world, converted to
longitude/latitude and sampled bilinearly. Longitude wraps around the seam (the texture is padded
with one wrapped column on each side, so there is no reflection or clamp at ±180°); latitude
clamps at the poles. Sampling is done by :func:`torch.nn.functional.grid_sample`, a fused CPU/GPU
kernel, on the log image.

Anti-aliasing: when the panorama is finer than the camera (more than two panorama pixels per
camera pixel at the principal point), it is box-filtered down to match first, so
bilinear sampling sees a texture matched to the pixel footprint and a slowly rotating view does
not flicker. Sampling happens in the log domain: L = log(ε + I) of the prefiltered image is
interpolated (for an 8-bit image I is its value scaled to [0, 1]; for a float image, radiance).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from spikegyro.sim.camera import Camera
from spikegyro.sim.panorama import Panorama


def prefilter(intensity: np.ndarray, camera: Camera) -> np.ndarray:
    """Box-filter ``intensity`` (H, W) down to about one panorama pixel per camera pixel.

    Only when the panorama has at least two pixels per camera pixel (at the principal point);
    the whole image is resampled, so the equirectangular mapping is unchanged.
    """
    h, w = intensity.shape
    ratio = (w / (2 * np.pi)) * camera.pixel_angle_rad
    if ratio < 2:
        return intensity
    size = (max(2, round(w / ratio)), max(1, round(h / ratio)))
    image = Image.fromarray(np.ascontiguousarray(intensity, dtype=np.float32), mode="F")
    return np.asarray(image.resize(size, Image.Resampling.BOX), dtype=np.float32)


class Renderer:
    """Renders log intensity views of one panorama through one camera.

    Args:
        panorama: the scene.
        camera: intrinsics and resolution.
        eps: offset of the log, L = log(eps + I).
        rays: unit viewing rays (3, height * width) of the pixels, row-major; default the
            camera's pinhole rays (a distorted lens gives others, see :mod:`spikegyro.sim.sensor`).
    """

    def __init__(
        self,
        panorama: Panorama,
        camera: Camera,
        eps: float = 1e-3,
        rays: np.ndarray | None = None,
    ) -> None:
        self.camera = camera
        log_img = np.log(eps + prefilter(panorama.intensity, camera)).astype(np.float32)
        w = log_img.shape[1]
        padded = np.concatenate([log_img[:, -1:], log_img, log_img[:, :1]], axis=1)
        self._texture = torch.from_numpy(np.ascontiguousarray(padded))[None, None]
        # grid_sample(align_corners=False) maps −1..1 onto the outer edges of the padded texture;
        # longitude −π..π must land on the outer edges of the unpadded part.
        self._scale = np.float32([w / ((w + 2) * np.pi), 2.0 / np.pi])
        # Shrunk by 2e-6 so float32 rounding can never push |d_y| past 1 (arcsin would give NaN);
        # the latitude error this causes is below 0.12° within 0.12° of a pole, nil elsewhere.
        rays = camera.rays if rays is None else np.asarray(rays, dtype=np.float64)
        self._rays = (rays * (1.0 - 2e-6)).astype(np.float32)

    def render_log(self, rotations: np.ndarray) -> np.ndarray:
        """Log intensity views for camera-to-world ``rotations`` (K, 3, 3) → (K, height, width)."""
        r = np.asarray(rotations, dtype=np.float32).reshape(-1, 3, 3)
        k = r.shape[0]
        cam = self.camera
        d = np.matmul(r, self._rays)  # (K, 3, P) world directions
        grid = np.empty((k, d.shape[2], 2), dtype=np.float32)
        # Contiguous temporaries, then one strided write each: much faster than strided math.
        np.multiply(np.arctan2(d[:, 0], d[:, 2]), self._scale[0], out=grid[..., 0])
        lat = np.arcsin(d[:, 1])
        np.multiply(lat, self._scale[1], out=grid[..., 1])
        out = F.grid_sample(
            self._texture,
            torch.from_numpy(grid).view(1, k * cam.height, cam.width, 2),
            mode="bilinear",
            padding_mode="border",
            align_corners=False,
        )
        return out.numpy().reshape(k, cam.height, cam.width)


def render(
    panorama: Panorama, rotation: np.ndarray, camera: Camera | None = None, eps: float = 1e-3
) -> np.ndarray:
    """Log intensity L = log(eps + I) seen through ``camera`` at camera-to-world ``rotation``.

    ``rotation`` is (3, 3) → image (height, width), or (K, 3, 3) → (K, height, width). For many
    frames of one panorama, build a :class:`Renderer` once instead.
    """
    rotation = np.asarray(rotation)
    views = Renderer(panorama, camera or Camera(), eps).render_log(rotation)
    return views[0] if rotation.ndim == 2 else views
