"""A realistic DAVIS240C sensor model, drawn at random for every sequence.

The ideal sensor of :mod:`spikegyro.sim.esim` (thresholds ~ N(0.45, 0.05), a perfect pinhole, no
noise) gives a network data that are denser, cleaner and more regular than a real DAVIS240C. A
:class:`SensorPreset` holds ranges; :meth:`SensorPreset.draw` draws one :class:`SensorParams` per
sequence, which :func:`spikegyro.sim.esim.simulate` applies:

- **Contrast thresholds**, ON and OFF separately, over a wide range. Stoffregen et al., "Reducing
  the Sim-to-Real Gap for Event Cameras" (ECCV 2020), showed that what transfers is a wide
  threshold range chosen so that the events per pixel (and per second) of the simulated data
  match those of real data; they train with thresholds from about 0.2 to 1.5 log units, ESIM
  (Rebecq et al., CoRL 2018) and v2e (Hu et al., CVPR Workshops 2021) default to 0.2 to 0.5.
  Following their recipe rather than their numbers, the mean threshold here is log-uniform in
  [0.1, 0.6] (0.1 is about the DAVIS240C's minimum contrast sensitivity, Brandli 2014): with our
  scenes and rotations that spreads 100 ms windows over the span of real DAVIS240C rotation
  recordings (0.2 to 5.6 M events/s in the Event Camera Dataset; docs/simulator.md has the
  measurement), where U(0.2, 1.5) left the median window at 0.1 M events/s. ON/OFF differ by a
  factor C_on/C_off log-uniform in [0.8, 1.8]: real ON and OFF thresholds are set by separate
  biases, and real recordings are OFF-heavy (the four ECD rotation windows have 42 % ON events,
  which takes C_on/C_off ≈ 1.4; the Rueckauer & Delbruck recording 51 %, ≈ 1).
- **Per-pixel threshold mismatch**, std U(0.02, 0.06) log units: Lichtsteiner et al. (JSSC 2008)
  and Brandli et al. (JSSC 2014) report a 2.1 % contrast mismatch, v2e defaults to 0.03 and its
  'noisy' model to 0.05.
- **Refractory period**, log-uniform in [1, 3] ms (v2e's default is 500 µs; the DAVIS
  refractory bias spans µs to ms). Measured with ``spikegyro compare-stats``: no pixel of the
  four Event Camera Dataset rotation windows fires twice within 1.36 ms, none of the Rueckauer &
  Delbruck recording within 2.9 ms, while an ideal simulated sensor puts up to a third of its
  same-pixel intervals under 1 ms (bursts of threshold crossings as an edge passes).
- **Background activity**: shot noise (random polarity) log-uniform in [0.05, 2] Hz per pixel
  and leak events (ON) in [0.01, 0.5] Hz per pixel (v2e: leak 0.01 Hz by default and 0.1 Hz in
  its 'noisy' model, shot noise 0.001 Hz by default and 5 Hz in 'noisy'; the DVS/DAVIS papers
  report background activity of the order of 0.1 Hz per pixel at room temperature).
- **Hot pixels**: 0 to 20 pixels firing at a rate log-uniform in [20, 1000] Hz (Stoffregen 2020
  adds such pixels to their training data; real DAVIS240C recordings show a handful).
- **Photoreceptor bandwidth**: a first-order low-pass on log intensity whose cutoff scales with
  intensity, as v2e models it: f_c(I) = f_white · min(1, (I + 20/255) / (1 + 20/255)) with I the
  linear intensity (white = 1). f_white is log-uniform in [150, 3000] Hz: v2e defaults to 300 Hz
  (30 Hz in its 'noisy' model), Brandli 2014 gives a pixel bandwidth of a few kHz in bright light.
  Events of dark pixels come late and smeared.
- **Lens**: radial-tangential distortion (k1, k2, p1, p2, k3) around the Event Camera Dataset's
  DAVIS240C calibration (k1 = -0.368, k2 = 0.151, p1, p2 ~ 1e-3, k3 = 0; Mueggler et al. 2017)
  and a principal point off centre (the ECD's is at (132, 111) for a 240x180 sensor): the sensor
  sees a distorted image. Datasets then map the events onto the ideal pinhole with the same
  per-pixel lookup table that ``spikegyro predict --calib`` uses
  (:meth:`spikegyro.events.calib.Calibration.map_events`), so the network is trained on what it
  will be fed, holes and all.

Scenes: the preset also mixes in sparse and office-like panoramas (:mod:`spikegyro.sim.indoor`)
so that event rates cover those of real rotation recordings (0.2 to 5 M events/s).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration
from spikegyro.sim.camera import Camera

Range = tuple[float, float]


@dataclass(frozen=True)
class EventSimConfig:
    """Event-camera model (thresholds in log-intensity units, times in µs, rates in Hz)."""

    contrast_on: float = 0.45
    contrast_off: float = 0.45
    mismatch_std: float = 0.03
    noise_std: float = 0.01
    min_contrast: float = 0.01
    refractory_us: int = 0
    shot_noise_hz: float = 0.0
    leak_hz: float = 0.0
    eps: float = 1e-3
    max_px_per_frame: float = 0.5
    min_frame_rate_hz: float = 500.0
    chunk_frames: int = 16


@dataclass(frozen=True)
class SensorParams:
    """One drawn sensor (thresholds in log units, times in µs, rates in Hz, lens in pixels).

    Attributes:
        contrast_on, contrast_off: nominal thresholds.
        mismatch_std: per-pixel threshold std.
        refractory_us: refractory period.
        shot_noise_hz, leak_hz: background activity per pixel.
        hot_pixels, hot_pixel_hz: number of hot pixels and the rate of each.
        cutoff_hz: photoreceptor 3 dB bandwidth at white (I = 1); 0 = unlimited.
        focal_scale, dcx, dcy: the sensor's focal length relative to the ideal camera's and its
            principal point offset, pixels.
        k1, k2, p1, p2, k3: radial-tangential distortion (OpenCV's plumb bob).
    """

    contrast_on: float
    contrast_off: float
    mismatch_std: float = 0.03
    refractory_us: int = 0
    shot_noise_hz: float = 0.0
    leak_hz: float = 0.0
    hot_pixels: int = 0
    hot_pixel_hz: float = 0.0
    cutoff_hz: float = 0.0
    focal_scale: float = 1.0
    dcx: float = 0.0
    dcy: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def event_config(self, config: EventSimConfig) -> EventSimConfig:
        """``config`` with this sensor's thresholds, mismatch, refractory period and noise."""
        return replace(
            config,
            contrast_on=self.contrast_on,
            contrast_off=self.contrast_off,
            mismatch_std=self.mismatch_std,
            refractory_us=self.refractory_us,
            shot_noise_hz=self.shot_noise_hz,
            leak_hz=self.leak_hz,
        )

    def calibration(self, camera: Camera) -> Calibration:
        """The real sensor's intrinsics and distortion, around the ideal ``camera``."""
        return Calibration(
            camera.fx * self.focal_scale,
            camera.fy * self.focal_scale,
            camera.cx + self.dcx,
            camera.cy + self.dcy,
            self.k1,
            self.k2,
            self.p1,
            self.p2,
            self.k3,
        )

    def attrs(self) -> dict[str, Any]:
        """HDF5 attributes: every parameter, prefixed ``sensor_``."""
        return {f"sensor_{k}": v for k, v in asdict(self).items()}


def sensor_rays(calib: Calibration, width: int, height: int) -> np.ndarray:
    """Unit viewing rays (3, height * width), row-major, of a distorted sensor's pixels.

    Pixel (u, v) sees the ray that :meth:`Calibration.pixel_rays` undistorts it to, so a scene
    point at normalised ideal coordinates (x, y) is imaged at ``calib.distort(x, y)``.
    """
    v, u = np.mgrid[0:height, 0:width]
    x, y = calib.pixel_rays(u.ravel(), v.ravel())
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError(f"distortion {calib}: the lens model folds over inside the sensor.")
    d = np.stack([x, y, np.ones_like(x)])
    return d / np.linalg.norm(d, axis=0)


def sensor_camera(calib: Calibration, width: int, height: int) -> Camera:
    """The pinhole part of a calibration as a :class:`Camera` (for frame-rate planning)."""
    return Camera(width, height, calib.fx, calib.fy, calib.cx, calib.cy)


@dataclass(frozen=True)
class SensorPreset:
    """Ranges from which :meth:`draw` takes one sensor per sequence, and the scene mix.

    Ranges are (low, high); ``*_log`` ranges are sampled log-uniformly. ``scenes`` gives the
    probabilities of the scene kinds: sparse shapes, office, photograph, procedural.
    """

    contrast_log: Range = (0.1, 0.6)
    on_off_ratio_log: Range = (0.8, 1.8)
    mismatch_std: Range = (0.02, 0.06)
    refractory_us_log: Range = (1000.0, 3000.0)
    shot_noise_hz_log: Range = (0.05, 2.0)
    leak_hz_log: Range = (0.01, 0.5)
    hot_pixels: tuple[int, int] = (0, 20)
    hot_pixel_hz_log: Range = (20.0, 1000.0)
    cutoff_hz_log: Range = (150.0, 3000.0)
    focal_scale: Range = (0.97, 1.03)
    principal_offset_px: Range = (-20.0, 20.0)
    k1: Range = (-0.40, -0.32)
    k2: Range = (0.12, 0.22)
    p: Range = (-1e-3, 1e-3)
    k3: Range = (0.0, 0.0)
    detail_strength: Range = (0.0, 0.4)
    scenes: tuple[float, float, float, float] = (0.25, 0.3, 0.25, 0.2)
    undistort: bool = True

    def draw(self, rng: np.random.Generator, scale: float = 1.0) -> SensorParams:
        """One sensor; ``scale`` = sensor width / 240 scales the principal point offset."""

        def logu(r: Range) -> float:
            return float(np.exp(rng.uniform(np.log(r[0]), np.log(r[1]))))

        def u(r: Range) -> float:
            return float(rng.uniform(*r))

        mean, ratio = logu(self.contrast_log), logu(self.on_off_ratio_log)
        # ON and OFF differ by `ratio` around `mean` (geometric mean = mean).
        return SensorParams(
            contrast_on=float(mean * np.sqrt(ratio)),
            contrast_off=float(mean / np.sqrt(ratio)),
            mismatch_std=u(self.mismatch_std),
            refractory_us=round(logu(self.refractory_us_log)),
            shot_noise_hz=logu(self.shot_noise_hz_log),
            leak_hz=logu(self.leak_hz_log),
            hot_pixels=int(rng.integers(self.hot_pixels[0], self.hot_pixels[1] + 1)),
            hot_pixel_hz=logu(self.hot_pixel_hz_log),
            cutoff_hz=logu(self.cutoff_hz_log),
            focal_scale=u(self.focal_scale),
            dcx=u(self.principal_offset_px) * scale,
            dcy=u(self.principal_offset_px) * scale,
            k1=u(self.k1),
            k2=u(self.k2),
            p1=u(self.p),
            p2=u(self.p),
            k3=u(self.k3),
        )


SENSOR_PRESETS: dict[str, SensorPreset | None] = {
    "ideal": None,  # the paper's simulator: EventSimConfig as given, no sensor effects
    "davis240c": SensorPreset(),
}


def sensor_preset(name: str) -> SensorPreset | None:
    """The preset called ``name`` (None for ``ideal``)."""
    if name not in SENSOR_PRESETS:
        raise InputError(f"--sensor {name}: choose one of {', '.join(SENSOR_PRESETS)}.")
    return SENSOR_PRESETS[name]


# v2e's intensity scaling of the photoreceptor time constant: 8-bit value + 20, over 255 + 20.
DARK_OFFSET = 20.0 / 255.0


def cutoff_scale(log_intensity: np.ndarray, eps: float) -> np.ndarray:
    """Bandwidth factor in (0, 1] of pixels with log intensity ``log(eps + I)``, I in [0, 1]."""
    intensity = np.exp(log_intensity) - np.float32(eps)
    return np.minimum((intensity + DARK_OFFSET) / (1.0 + DARK_OFFSET), 1.0).astype(np.float32)


class Photoreceptor:
    """First-order low-pass of log intensity with an intensity-dependent cutoff, over frames.

    Between frames the input is linear in time (as ESIM assumes), and the filter
    τ dy/dt = x − y has the exact solution for a ramp from a to b over Δt:
    y(Δt) = b − (b − a) g + (y₀ − a) e, with r = Δt/τ, e = e^{−r} and g = (1 − e)/r (written so
    that nothing cancels when Δt ≪ τ). τ = 1 / (2π f_c(I)) uses the intensity of the frame at
    the end of the interval. The state starts at the first frame (a steady scene).

    Args:
        first: (P,) log intensity of the first frame, at t = 0.
        cutoff_hz: 3 dB bandwidth at white.
        eps: offset of the log (L = log(eps + I)).
    """

    def __init__(self, first: np.ndarray, cutoff_hz: float, eps: float) -> None:
        self.y = first.astype(np.float32).copy()
        self.x = self.y.copy()
        self.t = 0.0
        self.tau_white = 1.0 / (2.0 * np.pi * cutoff_hz)
        self.eps = eps

    def __call__(self, frames: np.ndarray, times_s: np.ndarray) -> np.ndarray:
        """Filtered frames (K, P) for input ``frames`` (K, P) at ``times_s`` (K,) seconds."""
        out = np.empty_like(frames, dtype=np.float32)
        for k in range(frames.shape[0]):
            b = frames[k]
            dt = float(times_s[k]) - self.t
            r = np.float32(dt / self.tau_white) * cutoff_scale(b, self.eps)
            decay = np.exp(-r)
            self.y = b - (b - self.x) * (-np.expm1(-r) / r) + (self.y - self.x) * decay
            self.x, self.t = b, float(times_s[k])
            out[k] = self.y
        return out


def hot_pixel_events(
    params: SensorParams, n_pixels: int, duration_s: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poisson events of ``params.hot_pixels`` distinct random pixels at ``hot_pixel_hz`` each.

    Returns pixel index, time (s) and polarity (True = ON, each pixel with its own ON share).
    """
    count = min(params.hot_pixels, n_pixels)
    if count == 0 or params.hot_pixel_hz <= 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
    pixels = rng.choice(n_pixels, count, replace=False)
    per_pixel = rng.poisson(params.hot_pixel_hz * duration_s, count)
    on_share = rng.uniform(0.0, 1.0, count)
    pix = np.repeat(pixels, per_pixel)
    return (
        pix,
        rng.uniform(0.0, duration_s, pix.size),
        rng.random(pix.size) < np.repeat(on_share, per_pixel),
    )
