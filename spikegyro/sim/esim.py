"""ESIM's event generation from rendered log-intensity frames, vectorised over pixels.

Algorithm (Rebecq et al., CoRL 2018): each pixel keeps a reference log intensity, set by the first
rendered frame. Between two consecutive frames the log intensity of a pixel is linear in time;
whenever it moves a contrast threshold above (ON) or below (OFF) the reference, an event is
emitted at the linearly interpolated crossing time and the reference moves by exactly that
threshold, so one frame interval can hold several events per pixel.

Frames are rendered adaptively: at a rate such that no pixel moves more than
``max_px_per_frame`` pixels between frames (the rotational image speed is known in closed form
from ω), never slower than ``min_frame_rate_hz``.

Thresholds: the nominal ON/OFF values, per-pixel mismatch (drawn once per pixel, as ESIM's
sigma), and per-crossing noise (redrawn after every event of that pixel), all clamped at
``min_contrast``. Optional sensor effects, off by default: a refractory period (events closer
than it to the previous event of the same pixel are dropped, the reference still moves), shot
noise (Poisson events of random polarity) and leak events (Poisson ON events), both in events
per pixel per second. A :class:`~spikegyro.sim.sensor.SensorParams` passed to :func:`simulate`
sets these and adds hot pixels, the photoreceptor's low-pass and a distorted lens.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.sim.camera import Camera
from spikegyro.sim.panorama import Panorama
from spikegyro.sim.render import Renderer
from spikegyro.sim.sensor import (
    EventSimConfig,
    Photoreceptor,
    SensorParams,
    hot_pixel_events,
    sensor_camera,
    sensor_rays,
)
from spikegyro.sim.trajectory import Trajectory


def frame_times(
    trajectory: Trajectory,
    camera: Camera,
    duration_s: float,
    max_px_per_frame: float = 0.5,
    min_frame_rate_hz: float = 500.0,
) -> np.ndarray:
    """Render times in seconds (first 0, last ``duration_s``) for adaptive sampling.

    The frame rate at time t is max(max image speed(ω(t)) / max_px_per_frame, floor); frames sit
    where its integral crosses an integer, so no pixel moves more than the bound between frames.
    """
    # ω is smooth, so a 0.5 ms grid resolves the frame rate; frames still land anywhere.
    grid = np.linspace(0.0, duration_s, max(2, int(np.ceil(duration_s / 5e-4)) + 1))
    rate = np.maximum(
        camera.max_flow(trajectory.omega_at(grid)) / max_px_per_frame, min_frame_rate_hz
    )
    count = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(grid))])
    n = max(1, int(np.ceil(count[-1])))
    times = np.interp(np.arange(n + 1) * (count[-1] / n), count, grid)
    times[-1] = duration_s
    return times


class _EventGenerator:
    """Per-pixel ESIM state over a stream of frames (flattened to P pixels).

    Thresholds are kept as (2, P) arrays indexed by polarity: row 0 OFF, row 1 ON.
    """

    def __init__(self, first: np.ndarray, config: EventSimConfig, rng: np.random.Generator):
        p = first.size
        self.config = config
        self.rng = rng
        self.floor = np.float32(config.min_contrast)
        nominal = np.array([[config.contrast_off], [config.contrast_on]], np.float32)
        mismatch = np.float32(config.mismatch_std) * rng.standard_normal((2, p), np.float32)
        self.base = np.maximum(nominal + mismatch, self.floor)
        self.c = self._noisy(self.base)
        self.ref = first.astype(np.float32).copy()
        self.prev = self.ref.copy()
        self.t_prev = 0.0
        self.last_t = np.full(p, -np.inf)
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def _noisy(self, base: np.ndarray) -> np.ndarray:
        """Thresholds for the next crossing: ``base`` plus per-crossing noise, clamped."""
        if self.config.noise_std <= 0:
            return base.copy()
        noise = self.rng.standard_normal(base.shape, np.float32)
        return np.maximum(base + np.float32(self.config.noise_std) * noise, self.floor)

    def push(self, frames: np.ndarray, times_s: np.ndarray) -> None:
        """Consume frames (K, P) of log intensity rendered at ``times_s`` (K,) seconds."""
        # Cheap vectorised screen: only pixels whose signal leaves the threshold band around
        # their current reference somewhere in this chunk can fire.
        high = frames.max(axis=0) - self.ref >= self.c[1]
        hot = np.flatnonzero(high | (frames.min(axis=0) - self.ref <= -self.c[0]))
        if hot.size:
            seq = np.concatenate([self.prev[None, hot], frames[:, hot]], axis=0)
            t = np.concatenate([[self.t_prev], times_s])
            pix, ts, pol = self._fire(hot, seq, t)
            # Chunks cover consecutive time spans, so sorting each one sorts the whole stream.
            t_us = np.rint(ts * 1e6).astype(np.int64)
            order = np.argsort(t_us)  # deterministic; the order of equal times is irrelevant
            self.parts.append((pix[order], t_us[order], pol[order]))
        self.prev = frames[-1].copy()
        self.t_prev = float(times_s[-1])

    def _fire(self, pix: np.ndarray, seq: np.ndarray, t: np.ndarray):
        """ESIM over frame intervals k = 0..K-1 for the pixels ``pix`` (signals ``seq``)."""
        ref, c = self.ref[pix], self.c[:, pix]
        noisy = self.config.noise_std > 0
        crossings: list[tuple[np.ndarray, int, np.ndarray, np.ndarray]] = []
        for k in range(seq.shape[0] - 1):
            l1 = seq[k + 1]
            d = l1 - ref
            up = d >= c[1]
            idx = np.flatnonzero(up | (d <= -c[0]))
            pol = up[idx]
            while idx.size:  # one pass per threshold crossed within this frame interval
                row = pol.view(np.uint8)
                step = c[row, idx]
                level = ref[idx] + np.where(pol, step, -step)
                ref[idx] = level
                crossings.append((idx, k, level, pol))
                if noisy:
                    c[row, idx] = self._noisy(self.base[row, pix[idx]])
                # Only pixels that just fired can cross again in this interval.
                d = l1[idx] - level
                up = d >= c[1, idx]
                keep = up | (d <= -c[0, idx])
                idx, pol = idx[keep], up[keep]
        self.ref[pix], self.c[:, pix] = ref, c
        # Timestamps for all crossings at once: linear interpolation within their interval.
        local = np.concatenate([x[0] for x in crossings])
        k = np.concatenate([np.full(x[0].size, x[1]) for x in crossings])
        level = np.concatenate([x[2] for x in crossings])
        pol = np.concatenate([x[3] for x in crossings])
        a, b = seq[k, local], seq[k + 1, local]
        span = b - a
        frac = np.minimum(np.maximum((level - a) / np.where(span == 0, 1, span), 0), 1)
        ts = t[k] + frac * (t[k + 1] - t[k])
        g = pix[local]
        if self.config.refractory_us > 0:
            g, ts, pol = self._refractory(g, ts, pol)
        return g, ts, pol

    def _refractory(self, g: np.ndarray, ts: np.ndarray, pol: np.ndarray):
        """Drop events closer than the refractory period to the pixel's previous kept event."""
        order = np.lexsort((ts, g))
        g, ts, pol = g[order], ts[order], pol[order]
        starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
        rank = np.arange(g.size) - np.repeat(starts, np.diff(np.r_[starts, g.size]))
        keep = np.zeros(g.size, bool)
        refractory = self.config.refractory_us * 1e-6
        for r in range(int(rank.max()) + 1 if g.size else 0):  # each pixel once per rank
            i = np.flatnonzero(rank == r)
            ok = ts[i] - self.last_t[g[i]] >= refractory
            keep[i[ok]] = True
            self.last_t[g[i[ok]]] = ts[i[ok]]
        return g[keep], ts[keep], pol[keep]

    def collect(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All events so far, sorted by time: pixel index, t (µs), polarity (True = ON)."""
        if not self.parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
        pix, t_us, pol = (np.concatenate(parts) for parts in zip(*self.parts, strict=True))
        return pix, t_us, pol


def _noise_events(
    config: EventSimConfig, n_pixels: int, duration_s: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    parts = []
    for rate, on_fraction in ((config.shot_noise_hz, 0.5), (config.leak_hz, 1.0)):
        if rate <= 0:
            continue
        n = rng.poisson(rate * n_pixels * duration_s)
        parts.append(
            (
                rng.integers(0, n_pixels, n),
                rng.uniform(0.0, duration_s, n),
                rng.random(n) < on_fraction,
            )
        )
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
    return tuple(np.concatenate(a) for a in zip(*parts, strict=True))  # type: ignore[return-value]


def _with_noise(
    signal: tuple[np.ndarray, np.ndarray, np.ndarray],
    config: EventSimConfig,
    sensor: SensorParams | None,
    num_pixels: int,
    duration_s: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The signal events ``(pix, t_us, pol)`` merged in time order (stable: signal first at
    equal times) with the noise events of ``config`` and, for a drawn sensor, its hot pixels'.

    The noise is drawn from ``rng`` before the hot pixels, so a seed gives the same events.
    """
    pix, t_us, pol = signal
    noise_pix, noise_t, noise_pol = _noise_events(config, num_pixels, duration_s, rng)
    if sensor is not None:
        hot_pix, hot_t, hot_pol = hot_pixel_events(sensor, num_pixels, duration_s, rng)
        noise_pix = np.concatenate([noise_pix, hot_pix])
        noise_t = np.concatenate([noise_t, hot_t])
        noise_pol = np.concatenate([noise_pol, hot_pol])
    if noise_pix.size:
        pix, pol = np.concatenate([pix, noise_pix]), np.concatenate([pol, noise_pol])
        t_us = np.concatenate([t_us, np.rint(noise_t * 1e6).astype(np.int64)])
        order = np.argsort(t_us, kind="stable")
        pix, t_us, pol = pix[order], t_us[order], pol[order]
    return pix, t_us, pol


def simulate(
    panorama: Panorama,
    trajectory: Trajectory,
    camera: Camera | None = None,
    config: EventSimConfig | None = None,
    rng: np.random.Generator | None = None,
    duration_s: float | None = None,
    renderer: Renderer | None = None,
    sensor: SensorParams | None = None,
) -> Recording:
    """Simulate the events of ``camera`` rotating along ``trajectory`` inside ``panorama``.

    Args:
        panorama: the scene.
        trajectory: the motion; ``duration_s`` defaults to its duration.
        camera: intrinsics (default 240x180, f = 200 px).
        config: the sensor model (default :class:`EventSimConfig`).
        rng: randomness for thresholds and noise (default: seed 0).
        duration_s: simulated time in seconds.
        renderer: a prebuilt renderer for this panorama and camera (saves the prefilter); with
            ``sensor``, it must render through the sensor's lens (:func:`sensor_rays`).
        sensor: a drawn real sensor (see :mod:`spikegyro.sim.sensor`): replaces the thresholds,
            mismatch, refractory period and noise rates of ``config``, adds hot pixels and the
            photoreceptor low-pass, and images the scene through its distorted lens, so events
            are at the sensor's (distorted) pixel positions; None: the ideal sensor.

    Returns:
        A :class:`Recording`: events sorted by t (µs, from 0), ground-truth ω at 1 kHz with
        ang_ts = 0, 1000, ..., duration (inclusive), and attrs describing the sensor.
    """
    camera = camera or Camera()
    config = config or EventSimConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    duration_s = trajectory.duration_s if duration_s is None else float(duration_s)
    optics = camera
    if sensor is not None:
        config = sensor.event_config(config)
        calib = sensor.calibration(camera)
        optics = sensor_camera(calib, camera.width, camera.height)
        if renderer is None:
            rays = sensor_rays(calib, camera.width, camera.height)
            renderer = Renderer(panorama, camera, config.eps, rays)
    renderer = renderer or Renderer(panorama, camera, config.eps)
    times = frame_times(
        trajectory, optics, duration_s, config.max_px_per_frame, config.min_frame_rate_hz
    )
    first = renderer.render_log(trajectory.rotation_at(times[:1])).reshape(-1)
    gen = _EventGenerator(first, config, rng)
    lowpass = None
    if sensor is not None and sensor.cutoff_hz > 0:
        lowpass = Photoreceptor(first, sensor.cutoff_hz, config.eps)
    for i in range(1, times.size, config.chunk_frames):
        chunk = times[i : i + config.chunk_frames]
        frames = renderer.render_log(trajectory.rotation_at(chunk)).reshape(chunk.size, -1)
        gen.push(frames if lowpass is None else lowpass(frames, chunk), chunk)
    pix, t_us, pol = _with_noise(gen.collect(), config, sensor, first.size, duration_s, rng)
    y, x = np.divmod(pix, camera.width)
    events = EventArray.from_arrays(x, y, t_us, pol, camera.width, camera.height, validate=False)
    gyro_t = np.rint(np.arange(round(duration_s * 1000) + 1) * 1000.0).astype(np.int64)
    gyro = GyroTrace.from_arrays(gyro_t, trajectory.omega_at(gyro_t / 1e6))
    attrs = {
        "fx": camera.fx,
        "fy": camera.fy,
        "cx": camera.cx,
        "cy": camera.cy,
        "scene": panorama.name,
        "frames": int(times.size),
        **{f"esim_{k}": v for k, v in asdict(config).items()},
        **({} if sensor is None else sensor.attrs()),
    }
    return Recording(events=events, gyro=gyro, attrs=attrs)
