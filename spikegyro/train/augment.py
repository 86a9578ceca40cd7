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

Event density. A real DAVIS240C gives anything from 0.2 to 5.6 M events/s in the Event Camera
Dataset's rotation sequences, and an SNN trained on dense simulated windows degrades on sparse
ones (keeping 35 % of the events of simulated test windows raised SNN-6's error from 0.18 to
0.28; 10 % to 0.66). :func:`thin` keeps a random share of a window's events; the share is drawn
per window, U(keep_min, 1). :func:`add_noise_events` adds background activity: uniform events of
random polarity at a per-pixel rate. Neither changes the labels: the motion is the same, only
the sensor's sampling of it differs.

Aperture. Roll moves a pixel at radius r from the optical axis by ω·r, so its evidence lies in
the periphery: with only the events of the central quarter of the image, the shipped SNN-6 knows
nothing about roll (``scripts/analysis/roll_probe.py``), and real sparse scenes such as the
Event Camera Dataset's ``shapes`` put half their events there. :func:`keep_centre` keeps the
events inside a centred box, as a camera that sees texture only through an aperture would record;
the motion and so the labels are unchanged. The box is symmetric about the sensor centre, so it
commutes with both mirrors and with time inversion. Thinning keeps events by their position in
the stream, so it commutes with the mirrors (which keep the order) and, with the mask reversed,
with time inversion (which reverses it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from spikegyro.events.core import EventArray
from spikegyro.train.data import Window

HORIZONTAL_MIRROR = np.diag([-1.0, 1.0, 1.0])
VERTICAL_MIRROR = np.diag([1.0, -1.0, 1.0])
CENTRE_SIDE = (0.3, 0.7)  # the aperture's side as a share of the sensor's, drawn uniformly


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
    """Play the window backwards: times mirrored in the window, polarities swapped, ω -> -ω(T-τ)
    (on the event clock, step k's mean becomes step T-1-k's, negated)."""
    ev = window.events
    order = slice(None, None, -1)
    # Copies, not reversed views: every consumer (torch.from_numpy above all) gets plain arrays.
    # np.ascontiguousarray would not do, it keeps a one-element view's negative stride.
    events = replace(
        ev,
        x=ev.x[order].copy(),
        y=ev.y[order].copy(),
        t=(window.t_start_us + window.t_end_us - 1) - ev.t[order],
        p=(1 - ev.p[order]).astype(np.uint8),
    )
    if window.step_us is not None:  # labels are means over steps: the steps reverse
        return replace(
            window,
            events=events,
            omega=-window.omega[::-1].copy(),
            omega_start=-window.omega[-1].copy(),
            step_us=window.step_us[::-1].copy(),
        )
    labels = np.concatenate([window.omega_start[None], window.omega[:-1]])
    return replace(
        window,
        events=events,
        omega=-labels[::-1].copy(),
        omega_start=-window.omega[-1].copy(),
    )


def thin(window: Window, keep: np.ndarray) -> Window:
    """The window with only the events where the boolean mask ``keep`` (N,) is True."""
    return replace(window, events=window.events[np.asarray(keep, dtype=bool)])


def centre_mask(events: EventArray, fraction: float) -> np.ndarray:
    """Events whose pixel centre lies within ``fraction``·W/2 and ``fraction``·H/2 of the centre."""
    half_w, half_h = fraction * events.width / 2, fraction * events.height / 2
    dx = np.abs(events.x - (events.width - 1) / 2)
    dy = np.abs(events.y - (events.height - 1) / 2)
    return (dx < half_w) & (dy < half_h)


def keep_centre(window: Window, fraction: float) -> Window:
    """The window with only the events inside the centred box of ``fraction`` times each side."""
    return thin(window, centre_mask(window.events, fraction))


def add_noise_events(window: Window, rate_hz: float, rng: np.random.Generator) -> Window:
    """Add Poisson background events: ``rate_hz`` per pixel per second, uniform in the window.

    Pixels and times (µs in [t_start, t_end)) are uniform, polarities fair coins; the merged
    stream stays sorted by time (the original events first among equal times).
    """
    ev = window.events
    duration_s = (window.t_end_us - window.t_start_us) / 1e6
    n = int(rng.poisson(rate_hz * ev.width * ev.height * duration_s))
    if n == 0:
        return window
    t = np.concatenate([ev.t, rng.integers(window.t_start_us, window.t_end_us, n)])
    order = np.argsort(t, kind="stable")
    merged = EventArray.from_arrays(
        np.concatenate([ev.x, rng.integers(0, ev.width, n)])[order],
        np.concatenate([ev.y, rng.integers(0, ev.height, n)])[order],
        t[order],
        np.concatenate([ev.p, rng.integers(0, 2, n)])[order],
        ev.width,
        ev.height,
        validate=False,
    )
    return replace(window, events=merged)


@dataclass(frozen=True)
class AugmentConfig:
    """Probability of each augmentation (the paper: random flips and time inversion), and the
    event-density augmentation (off by default).

    Attributes:
        hflip, vflip, time_reverse: probabilities.
        keep_min: each window keeps a share U(keep_min, 1) of its events (1 = off).
        noise_hz: each window gains background events at a per-pixel rate U(0, noise_hz) Hz.
        centre: probability that a window keeps only the events of a centred box whose side is
            a share U(*CENTRE_SIDE) of the sensor's (0 = off).
    """

    hflip: float = 0.5
    vflip: float = 0.5
    time_reverse: float = 0.5
    keep_min: float = 1.0
    noise_hz: float = 0.0
    centre: float = 0.0

    @classmethod
    def of(cls, config: Any) -> AugmentConfig:
        """The augmentation a :class:`~spikegyro.train.presets.TrainConfig` asks for."""
        return cls(
            config.hflip,
            config.vflip,
            config.time_reverse,
            config.event_keep_min,
            config.noise_events_hz,
            config.centre_crop,
        )

    def __call__(self, window: Window, rng: np.random.Generator) -> Window:
        """Apply each augmentation independently with its probability."""
        draws = rng.random(3)
        if draws[0] < self.hflip:
            window = flip_horizontal(window)
        if draws[1] < self.vflip:
            window = flip_vertical(window)
        if draws[2] < self.time_reverse:
            window = reverse_time(window)
        # Drawn only when on, so the paper's augmentation keeps its random stream.
        if self.keep_min < 1.0:
            keep = rng.uniform(self.keep_min, 1.0)
            window = thin(window, rng.random(len(window.events)) < keep)
        if self.centre > 0 and rng.random() < self.centre:
            window = keep_centre(window, rng.uniform(*CENTRE_SIDE))
        if self.noise_hz > 0:  # after the aperture: background activity fills the whole sensor
            window = add_noise_events(window, rng.uniform(0.0, self.noise_hz), rng)
        return window

    @property
    def enabled(self) -> bool:
        flips = max(self.hflip, self.vflip, self.time_reverse) > 0
        return flips or self.keep_min < 1.0 or self.noise_hz > 0 or self.centre > 0
