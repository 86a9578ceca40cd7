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
"""

from spikegyro.sim.camera import Camera
from spikegyro.sim.esim import EventSimConfig, frame_times, simulate
from spikegyro.sim.panorama import Panorama, load_panorama, mirror_panorama
from spikegyro.sim.render import Renderer, render
from spikegyro.sim.trajectory import (
    Trajectory,
    TrajectoryConfig,
    random_rotation,
    random_trajectory,
    so3_exp,
    so3_log,
)

__all__ = [
    "Camera",
    "EventSimConfig",
    "Panorama",
    "Renderer",
    "Trajectory",
    "TrajectoryConfig",
    "frame_times",
    "load_panorama",
    "mirror_panorama",
    "random_rotation",
    "random_trajectory",
    "render",
    "simulate",
    "so3_exp",
    "so3_log",
]
