"""Training augmentations with their exact label transforms.

Mirrors. Flipping the image left-right (x -> W-1-x) is what the camera would see in a world
reflected by M = diag(-1, 1, 1) (camera frame x right, y down, z forward) while rotating as
M R(t) M. With Ṙ = R [ω]× the reflected camera obeys d/dt (M R M) = (M R M) [M [ω]× M], and
M [ω]× M = [det(M) M ω]×, so the gyro of the mirrored camera reads ω' = det(M) M ω: an angular
velocity is an axial vector. For M = diag(-1, 1, 1) that is (ω_x, -ω_y, -ω_z); the up-down flip
M = diag(1, -1, 1) gives (-ω_x, ω_y, -ω_z). The pixel mirror x -> W-1-x reflects about
c_x = (W-1)/2, the sensor centre in pixel-centre coordinates.

Time inversion. Played backwards, the camera retraces its path, so ω'(τ) = -ω(T - τ), and every
brightness change reverses its sign, so ON and OFF swap. Event times map t -> t0 + t1 - 1 - t
(µs) to stay inside [t0, t1) and keep the 1 ms bins aligned (bin k <-> bin T-1-k). The label of
new bin k is ω' at its end τ = k+1 ms, i.e. -ω(t0 + T - k - 1 ms): the old label of bin T-k-2,
or -ω(t0) for the last bin.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from spikegyro.events.core import EventArray
from spikegyro.train.data import Window

HORIZONTAL_MIRROR = np.diag([-1.0, 1.0, 1.0])
VERTICAL_MIRROR = np.diag([1.0, -1.0, 1.0])


def mirror_omega(omega: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Angular velocity (…, 3) seen by a camera in a world reflected by ``mirror`` (3x3)."""
    return (np.linalg.det(mirror) * omega @ mirror.T).astype(omega.dtype)


def flip_horizontal(window: Window) -> Window:
    """Mirror left-right: x -> W-1-x, ω -> (ω_x, -ω_y, -ω_z)."""
    ev = window.events
    events = replace(ev, x=(ev.width - 1 - ev.x).astype(np.int16))
    return _mirrored(window, events, HORIZONTAL_MIRROR)


def flip_vertical(window: Window) -> Window:
    """Mirror up-down: y -> H-1-y, ω -> (-ω_x, ω_y, -ω_z)."""
    ev = window.events
    events = replace(ev, y=(ev.height - 1 - ev.y).astype(np.int16))
    return _mirrored(window, events, VERTICAL_MIRROR)


def _mirrored(window: Window, events: EventArray, mirror: np.ndarray) -> Window:
    return replace(
        window,
        events=events,
        omega=mirror_omega(window.omega, mirror),
        omega_start=mirror_omega(window.omega_start, mirror),
    )


def reverse_time(window: Window) -> Window:
    """Play the window backwards: times mirrored in the window, polarities swapped, ω -> -ω(T-τ)."""
    ev = window.events
    order = slice(None, None, -1)
    events = replace(
        ev,
        x=ev.x[order],
        y=ev.y[order],
        t=(window.t_start_us + window.t_end_us - 1) - ev.t[order],
        p=(1 - ev.p[order]).astype(np.uint8),
    )
    labels = np.concatenate([window.omega_start[None], window.omega[:-1]])
    return replace(
        window,
        events=events,
        omega=-labels[::-1].copy(),
        omega_start=-window.omega[-1].copy(),
    )


@dataclass(frozen=True)
class AugmentConfig:
    """Probability of each augmentation (the paper: random flips and time inversion)."""

    hflip: float = 0.5
    vflip: float = 0.5
    time_reverse: float = 0.5

    def __call__(self, window: Window, rng: np.random.Generator) -> Window:
        """Apply each augmentation independently with its probability."""
        draws = rng.random(3)
        if draws[0] < self.hflip:
            window = flip_horizontal(window)
        if draws[1] < self.vflip:
            window = flip_vertical(window)
        if draws[2] < self.time_reverse:
            window = reverse_time(window)
        return window

    @property
    def enabled(self) -> bool:
        return max(self.hflip, self.vflip, self.time_reverse) > 0
