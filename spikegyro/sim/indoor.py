"""Indoor panoramas like the scenes of real event-camera recordings.

The Event Camera Dataset's rotation sequences (Mueggler et al., IJRR 2017) film a few dark shapes
on a white wall (``shapes``: about 0.2 M events/s), an office with posters, boxes and shelves
(``poster``, ``boxes``: up to 5 M events/s) and people in an office (``dynamic``). Photographs
with added texture cover neither end: they are denser than ``shapes`` and smoother than
``poster``. Two scene kinds fill the gap:

- :func:`sparse_panorama`: a plain, softly shaded background with a few sharp dark shapes
  (ellipses, rectangles, triangles) scattered uniformly over the sphere; most of every view is
  uniform, so events come only from the shapes' outlines.
- :func:`office_panorama`: walls of uniform paint meeting at vertical corners, a ceiling and a
  textured floor, posters with fine (pixel-scale) texture, boxes with shaded faces, and thin
  shelves and door frames.

Shapes are placed by angle (positions uniform on the sphere, sizes in degrees, longitude
stretched by 1/cos(latitude)), so they look the same wherever the camera points. Log-intensity
layers are built on the equirectangular grid and turned into intensities in (0, 1].
"""

from __future__ import annotations

import numpy as np

from spikegyro.sim.panorama import Panorama
from spikegyro.sim.procedural import fractal_noise, to_intensity


class _Canvas:
    """A log-intensity equirectangular image (height = width / 2) painted with shapes."""

    def __init__(self, width: int) -> None:
        self.height, self.width = width // 2, width
        self.log = np.zeros((self.height, width), np.float32)
        self.lat = (0.5 - (np.arange(self.height) + 0.5) / self.height) * np.pi  # rows, up > 0
        self.lon = ((np.arange(width) + 0.5) / width - 0.5) * 2.0 * np.pi

    def paint(
        self,
        lon0: float,
        lat0: float,
        half_w: float,
        half_h: float,
        value: float | np.ndarray,
        kind: str = "rect",
        angle: float = 0.0,
        add: bool = False,
    ) -> None:
        """Set (or add to) the log intensity inside one shape.

        Args:
            lon0, lat0: centre, radians.
            half_w, half_h: half extents, radians of arc (local tangent plane).
            value: log level, or an image (height, width) to copy from inside the shape.
            kind: "rect", "ellipse" or "triangle" (pointing along local +y before rotation).
            angle: rotation of the shape in its tangent plane, radians.
            add: add ``value`` to the current level instead of replacing it.
        """
        reach = np.hypot(half_w, half_h)
        rows = np.flatnonzero(np.abs(self.lat - lat0) <= reach)
        if rows.size == 0:
            return
        lat = self.lat[rows, None]
        dlon = (self.lon[None, :] - lon0 + np.pi) % (2.0 * np.pi) - np.pi
        x = dlon * np.cos(lat)
        y = lat0 - lat  # image y points down
        c, s = np.cos(angle), np.sin(angle)
        u, v = (c * x + s * y) / half_w, (-s * x + c * y) / half_h
        if kind == "ellipse":
            inside = u * u + v * v <= 1.0
        elif kind == "triangle":
            inside = (v <= 1.0) & (v >= 2.0 * np.abs(u) - 1.0)
        else:
            inside = (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0)
        r, col = np.nonzero(inside)
        target = (rows[r], col)
        level = value if np.isscalar(value) else np.asarray(value)[target]
        if add:
            self.log[target] += level
        else:
            self.log[target] = level


def _sphere_point(rng: np.random.Generator, max_lat: float = np.pi / 2) -> tuple[float, float]:
    """Longitude, latitude (radians) uniform on the sphere within |lat| <= max_lat."""
    z = rng.uniform(-np.sin(max_lat), np.sin(max_lat))
    return float(rng.uniform(-np.pi, np.pi)), float(np.arcsin(z))


def sparse_panorama(rng: np.random.Generator, width: int = 1280, name: str = "sparse"):
    """A few sharp dark shapes on a plain, softly shaded background (like ECD ``shapes``).

    20-80 shapes over the sphere (a 62° x 48° view sees about 1-6 whole ones), radius 2-8°, each
    0.5-3 log units darker than the wall (one in five lighter by 0.3-1); the wall's log shading
    has std 0.02-0.15 on scales of tens of degrees.
    """
    canvas = _Canvas(width)
    shading = fractal_noise(canvas.height, width, rng, beta=4.0)
    canvas.log += np.float32(rng.uniform(0.02, 0.15)) * shading
    for _ in range(int(rng.integers(20, 81))):
        lon, lat = _sphere_point(rng)
        radius = np.radians(rng.uniform(2.0, 8.0))
        aspect = rng.uniform(0.5, 1.0)
        kind = ("ellipse", "rect", "triangle")[int(rng.integers(3))]
        darker = rng.random() < 0.8
        offset = -rng.uniform(0.5, 3.0) if darker else rng.uniform(0.3, 1.0)
        canvas.paint(
            lon, lat, radius, radius * aspect, offset, kind, rng.uniform(0, np.pi), add=True
        )
    return Panorama(to_intensity(canvas.log), name)


def office_panorama(rng: np.random.Generator, width: int = 1280, name: str = "office"):
    """An office: uniform walls with corners, ceiling, textured floor, posters, boxes, shelves.

    Walls: 3-8 segments, each a uniform log level in [-1.5, 0]; ceiling above 17-40° of
    elevation, floor below; the floor carries 1/f texture. 10-40 posters (6-40° wide) show
    pixel-scale 1/f texture (β in [1.5, 2.5], log std 0.3-1.2), 5-25 boxes (4-20° wide) have a
    printed front (the same texture, log std up to 0.8) and a differently lit top, and 5-30 thin
    straight edges (shelves, frames) cross the walls. A smooth 1/f illumination (log std up to
    0.3) lies over everything.
    """
    canvas = _Canvas(width)
    lon, lat = canvas.lon[None, :], canvas.lat[:, None]
    corners = np.sort(rng.uniform(-np.pi, np.pi, int(rng.integers(3, 9))))
    segment = np.searchsorted(corners, lon) % corners.size
    canvas.log[:] = rng.uniform(-1.5, 0.0, corners.size)[segment]
    ceiling, floor = np.radians(rng.uniform(17.0, 40.0, 2))
    canvas.log[:] = np.where(lat > ceiling, rng.uniform(-0.6, 0.0), canvas.log)
    floor_texture = np.float32(rng.uniform(0.1, 0.5)) * fractal_noise(
        canvas.height, width, rng, beta=rng.uniform(2.0, 3.0)
    )
    canvas.log[:] = np.where(lat < -floor, rng.uniform(-2.0, -0.5) + floor_texture, canvas.log)
    poster_texture = fractal_noise(canvas.height, width, rng, beta=rng.uniform(1.5, 2.5))
    for _ in range(int(rng.integers(10, 41))):
        p_lon, p_lat = _sphere_point(rng, max_lat=ceiling * 0.8)
        half_w = np.radians(rng.uniform(3.0, 20.0))
        content = rng.uniform(-1.5, 0.5) + rng.uniform(0.3, 1.2) * poster_texture
        canvas.paint(p_lon, p_lat, half_w, half_w * rng.uniform(0.6, 1.5), content)
    for _ in range(int(rng.integers(5, 26))):
        b_lon = rng.uniform(-np.pi, np.pi)
        half_w = np.radians(rng.uniform(2.0, 10.0))
        half_h = half_w * rng.uniform(0.4, 1.2)
        b_lat = -floor + half_h * rng.uniform(0.0, 1.5)
        print_ = rng.uniform(0.0, 0.8) * poster_texture  # printed cardboard
        canvas.paint(b_lon, b_lat, half_w, half_h, rng.uniform(-2.5, 0.0) + print_)
        top = half_h * rng.uniform(0.15, 0.35)
        canvas.paint(b_lon, b_lat + half_h - top, half_w, top, rng.uniform(-2.0, 0.3))
    for _ in range(int(rng.integers(5, 31))):
        e_lon, e_lat = _sphere_point(rng, max_lat=ceiling)
        length = np.radians(rng.uniform(10.0, 60.0)) / 2
        thick = np.radians(rng.uniform(0.3, 1.0)) / 2
        vertical = rng.random() < 0.4
        half_w, half_h = (thick, length) if vertical else (length, thick)
        canvas.paint(e_lon, e_lat, half_w, half_h, rng.uniform(-1.5, 0.5), add=True)
    light = fractal_noise(canvas.height, width, rng, beta=4.0)
    canvas.log += np.float32(rng.uniform(0.0, 0.3)) * light
    return Panorama(to_intensity(canvas.log), name)
