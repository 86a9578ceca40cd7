"""Procedural panoramas and texture detail, so scene diversity is not capped by the photographs.

- :func:`fractal_noise`: Gaussian noise with a 1/f^β power spectrum (natural images have β ≈ 2),
  periodic in longitude so the seam is invisible.
- :func:`procedural_panorama`: 1/f texture plus random sharp-edged ellipses and rectangles.
- :func:`add_detail`: a photograph resampled to the camera's resolution and modulated by
  high-frequency 1/f texture. The bundled 1024x512 photographs are coarser than a 240x180,
  f = 200 px sensor (0.35° vs 0.29° per pixel) and some views (sky, plain walls) would give
  nearly empty windows; the detail keeps most 100 ms windows busy.

All functions take a NumPy ``Generator``; intensities are linear, in (0, 1].
"""

from __future__ import annotations

import numpy as np
import scipy.fft
from PIL import Image

from spikegyro.sim.camera import Camera
from spikegyro.sim.panorama import Panorama


def panorama_width(camera: Camera, multiple: int = 256) -> int:
    """Width (pixels) at which an equirectangular texel matches a camera pixel, rounded up."""
    exact = 2 * np.pi * max(camera.fx, camera.fy)
    return int(np.ceil(exact / multiple) * multiple)


def fractal_noise(
    height: int, width: int, rng: np.random.Generator, beta: float = 2.0, min_cycles: float = 1.0
) -> np.ndarray:
    """Zero-mean, unit-variance noise (height, width) with power spectrum ∝ 1/f^β.

    Frequencies below ``min_cycles`` cycles per image width are removed (a high-pass for
    detail layers). Periodic in both directions, hence seamless in longitude.
    """
    fy = np.fft.fftfreq(height)[:, None] * height
    fx = np.fft.rfftfreq(width)[None, :] * width
    # Longitude covers twice the angle of latitude per pixel count: measure both in cycles/width.
    f = np.hypot(fx, 2.0 * fy)
    amplitude = np.where(f >= min_cycles, np.maximum(f, 1e-9) ** (-beta / 2.0), 0.0)
    spectrum = np.empty(amplitude.shape, np.complex64)
    spectrum.real = rng.standard_normal(amplitude.shape, np.float32)
    spectrum.imag = rng.standard_normal(amplitude.shape, np.float32)
    spectrum *= amplitude.astype(np.float32)
    field = scipy.fft.irfft2(spectrum, s=(height, width), workers=1)
    field -= field.mean()
    return (field / max(field.std(), 1e-12)).astype(np.float32)


def random_shapes(height: int, width: int, rng: np.random.Generator, count: int) -> np.ndarray:
    """A log-intensity layer (height, width) of ``count`` sharp ellipses and rectangles.

    Each shape adds a random offset ~ N(0, 0.8²) in log units; longitudes wrap.
    """
    layer = np.zeros((height, width), np.float32)
    rows = np.arange(height)[:, None]
    cols = np.arange(width)[None, :]
    for _ in range(count):
        cy, cx = rng.uniform(0, height), rng.uniform(0, width)
        ry, rx = rng.uniform(0.01, 0.12) * height, rng.uniform(0.01, 0.12) * width
        offset = np.float32(rng.normal(0.0, 0.8))
        dy = (rows - cy) / ry
        dx = ((cols - cx + width / 2) % width - width / 2) / rx
        inside = dx**2 + dy**2 <= 1 if rng.random() < 0.5 else (abs(dx) <= 1) & (abs(dy) <= 1)
        layer += offset * inside
    return layer


def to_intensity(log_image: np.ndarray) -> np.ndarray:
    """exp of a log image, scaled so its brightest pixel is 1 (like a normalised photograph)."""
    return np.exp(log_image - log_image.max()).astype(np.float32)


def procedural_panorama(rng: np.random.Generator, width: int = 1280, name: str = "procedural"):
    """A random synthetic scene: smooth 1/f texture (β ~ U(3, 4)) plus 20-80 sharp shapes.

    The texture's log-intensity standard deviation is ~ U(0.4, 1.0). Rougher textures (β ≤ 2.5)
    put contrast at the pixel scale and give ten times more events than the photographs.
    """
    height = width // 2
    texture = fractal_noise(height, width, rng, beta=rng.uniform(3.0, 4.0))
    log_image = rng.uniform(0.4, 1.0) * texture
    log_image += random_shapes(height, width, rng, int(rng.integers(20, 81)))
    return Panorama(to_intensity(log_image), name)


def add_detail(
    panorama: Panorama, rng: np.random.Generator, strength: float, width: int = 1280
) -> Panorama:
    """Resample ``panorama`` to ``width`` x width/2 and modulate it by fine 1/f texture.

    The log intensity gains ``strength`` x unit-variance smooth noise (β = 4, above 4 cycles per
    width): shading-like variations on 5-90° scales that give otherwise blank sky and walls a few
    threshold crossings while leaving edges to the photograph. ``strength = 0`` only resamples.
    """
    image = Image.fromarray(panorama.intensity, mode="F")
    base = np.asarray(image.resize((width, width // 2), Image.Resampling.BILINEAR))
    if strength <= 0:
        return Panorama(base, panorama.name)
    detail = fractal_noise(width // 2, width, rng, beta=4.0, min_cycles=4.0)
    return Panorama(base * np.exp(strength * detail), f"{panorama.name}+detail")
