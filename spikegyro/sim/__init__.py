"""Event-camera simulator (ESIM-style) and dataset generator.

A pinhole camera rotates inside an equirectangular panorama; log-intensity frames are rendered
adaptively and turned into events with ESIM's algorithm; the ground truth is the exact
camera-frame angular velocity.

Low-level API (for tests and experiments)::

    import numpy as np
    from spikegyro.sim import (Camera, EventSimConfig, Trajectory, load_panorama,
                               mirror_panorama, render, simulate)

    cam = Camera()                                    # 240x180, f = 200 px, c = (120, 90)
    pano = load_panorama("scene.jpg")                 # or Panorama(intensity_array, "name")
    traj = Trajectory.constant([0.0, 2.0, 0.0], duration_s=0.1)   # pan at 2 rad/s
    traj.omega_at(0.05)                               # (3,) rad/s, camera frame
    traj.rotation_at([0.0, 0.05])                     # (2, 3, 3) camera-to-world
    log_image = render(pano, traj.rotation_at(0.0), cam)          # (180, 240) log(1e-3 + I)
    rec = simulate(pano, traj, cam, EventSimConfig(), np.random.default_rng(0))
    rec.events   # EventArray, t in µs from 0, sorted;  rec.gyro: ω at 1 kHz, 0..duration incl.

- ``Trajectory(t_s, omega, r0, duration_s)``: ω piecewise linear through arbitrary samples;
  ``Trajectory.constant``; ``random_trajectory(rng, duration_s, TrajectoryConfig())``;
  ``.reversed()`` (time reversal: ω'(t) = −ω(T − t)); ``.mirrored(axis)`` with
  ``mirror_panorama(pano, axis)`` for horizontal (axis 0) / vertical (axis 1) flips (exact when
  cx = (W − 1) / 2 and cy = (H − 1) / 2).
- Conventions: R is camera-to-world, dR/dt = R [ω]×; x right, y down, z forward; positive pan
  (ω_y > 0) moves the image towards −x, positive tilt (ω_x > 0) towards +y.

Dataset API: ``SimConfig`` and ``simulate_sequence(config, index, seed, split)`` give one
sequence deterministically from (seed, split, index); ``generate_dataset`` writes
``DIR/meta.json`` and ``DIR/{train,val,test}/seq_000123.h5`` (see :mod:`spikegyro.sim.dataset`).

Default scene mix: 70 % the bundled photographs (10 train / 1 val / 1 test, split by panorama)
resampled to about one texel per camera pixel with smooth 1/f shading detail (log std 0.4), 30 %
procedural panoramas (1/f texture and sharp shapes) from each sequence's own seed stream; every
sequence starts at a uniformly random orientation. Events per 100 ms window then have a median of
about 80 k and a 5th percentile of about 17 k at 240x180 (see BENCHMARKS.md).

Sensor model defaults (:class:`EventSimConfig`): thresholds ~ N(0.45, 0.05) per sequence (ON and
OFF drawn separately, dataset level), per-pixel mismatch std 0.03, per-crossing noise std 0.01,
clamped at 0.01; refractory period, shot noise and leak events off. Frames are rendered so no
pixel moves more than 0.5 px between them, at 500 Hz or faster. That is the ``ideal`` sensor
preset; ``SimConfig(sensor="davis240c")`` (``spikegyro simulate --sensor davis240c``) draws a real
sensor per sequence instead (wide ON/OFF thresholds, mismatch, refractory period, background
activity, hot pixels, photoreceptor bandwidth, lens distortion; :mod:`spikegyro.sim.sensor`) and
mixes in sparse and office scenes (:mod:`spikegyro.sim.indoor`).
"""

from spikegyro.sim.camera import Camera
from spikegyro.sim.dataset import SimConfig, generate_dataset, simulate_sequence
from spikegyro.sim.esim import frame_times, simulate
from spikegyro.sim.panorama import Panorama, load_panorama, mirror_panorama
from spikegyro.sim.render import Renderer, render
from spikegyro.sim.sensor import SENSOR_PRESETS, EventSimConfig, SensorParams, SensorPreset
from spikegyro.sim.trajectory import (
    Trajectory,
    TrajectoryConfig,
    random_rotation,
    random_trajectory,
    so3_exp,
    so3_log,
)

__all__ = [
    "SENSOR_PRESETS",
    "Camera",
    "EventSimConfig",
    "Panorama",
    "Renderer",
    "SensorParams",
    "SensorPreset",
    "SimConfig",
    "Trajectory",
    "TrajectoryConfig",
    "frame_times",
    "generate_dataset",
    "load_panorama",
    "mirror_panorama",
    "random_rotation",
    "random_trajectory",
    "render",
    "simulate",
    "simulate_sequence",
    "so3_exp",
    "so3_log",
]
