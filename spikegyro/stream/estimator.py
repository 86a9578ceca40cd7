"""The live gyroscope API that every estimator shares: feed event batches, get ω estimates.

An estimator is fed time-ordered event batches as they arrive (from a file, a camera driver's
callback or a ROS node) and answers with the estimates that the events seen so far complete::

    from spikegyro.cmax.live import CMaxEstimator
    from spikegyro.events.calib import Calibration

    gyro = CMaxEstimator(Calibration(245.0, 245.0, 120.0, 90.0))   # rate_hz=100 by default
    for batch in camera_batches():              # EventArray: x, y px, t µs (int64), p 0/1
        est = gyro.update(batch)                # zero or more new estimates
        for t_us, omega in zip(est.t_us, est.omega):
            control_loop(t_us, omega)           # ω (3,) rad/s, camera frame (x right, y down,
                                                # z forward), using only events up to t_us
    est = gyro.finish(t_end_us)                 # the estimates still due at the end

Both methods implement it: :class:`spikegyro.cmax.live.CMaxEstimator` (contrast
maximization, the one to use on real cameras) and
:class:`spikegyro.stream.predict.SNNEstimator` (the spiking network, one estimate per 1 ms
bin). ``spikegyro predict`` drives an estimator over a file with
:func:`spikegyro.stream.predict.predict_stream`.

Estimates are causal: the one stamped ``t`` uses only events with timestamps ``<= t``, so it can
be emitted as soon as an event later than ``t`` (or the end of the stream) has been seen.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from spikegyro.events.core import EventArray

ILL_FEW_EVENTS = 1
"""``Estimates.ill_posed`` bit: the window held fewer events than the estimator asks for."""
ILL_LITTLE_MOTION = 2
"""``Estimates.ill_posed`` bit: the estimate moves edges by less than a pixel over its window,
or by a few pixels that sharpen the events too little (contrast maximization's one-rotation
test), so a rotation that small cannot be told from none."""
ILL_NOT_ONE_ROTATION = 4
"""``Estimates.ill_posed`` bit: one rotation does not explain the window's events (parts of the
image disagree on it, nothing in them is sharpened by it, or they are one object in a still
view): the scene itself may move."""


@dataclass(frozen=True)
class Estimates:
    """A block of K angular-velocity estimates, each its own, in time order.

    Attributes:
        t_us: (K,) int64 time each estimate stands for, µs (it uses events up to this time).
        omega: (K, 3) float64 ω rad/s, camera frame.
        events: (K,) int64 events the estimate was computed from (-1 where not applicable).
        window_us: (K,) float64 span of those events, µs (NaN where not applicable).
        delay_us: (K,) float64 how far the events' mean time lies before ``t_us``, µs: the
            estimate is a mean rate over its window, so it lags the true ω by about this much
            (NaN where not applicable).
        contrast_gain: (K,) float64 contrast of the estimate over that of ω = 0 (1: no structure
            found; NaN where not applicable).
        ill_posed: (K,) uint8 bits :data:`ILL_FEW_EVENTS`, :data:`ILL_LITTLE_MOTION`,
            :data:`ILL_NOT_ONE_ROTATION`.
    """

    t_us: np.ndarray
    omega: np.ndarray
    events: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    window_us: np.ndarray = field(default_factory=lambda: np.zeros(0))
    delay_us: np.ndarray = field(default_factory=lambda: np.zeros(0))
    contrast_gain: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ill_posed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))

    def __post_init__(self) -> None:
        k = len(self.t_us)
        object.__setattr__(self, "t_us", np.asarray(self.t_us, dtype=np.int64).reshape(k))
        object.__setattr__(self, "omega", np.asarray(self.omega, dtype=np.float64).reshape(k, 3))
        for name, dtype, fill in (
            ("events", np.int64, -1),
            ("window_us", np.float64, np.nan),
            ("delay_us", np.float64, np.nan),
            ("contrast_gain", np.float64, np.nan),
            ("ill_posed", np.uint8, 0),
        ):
            value = np.asarray(getattr(self, name), dtype=dtype)
            if value.shape != (k,):  # not given: filled with "not applicable"
                value = np.full(k, fill, dtype=dtype)
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return len(self.t_us)

    @property
    def has_confidence(self) -> bool:
        """Whether the estimator reports its window and contrast gain (CMax does)."""
        return bool(len(self)) and bool(np.isfinite(self.contrast_gain).any())

    @classmethod
    def empty(cls) -> Estimates:
        """No estimates."""
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)))

    @staticmethod
    def concatenate(parts: list[Estimates]) -> Estimates:
        """The blocks one after the other."""
        if not parts:
            return Estimates.empty()
        return Estimates(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in (
                    "t_us",
                    "omega",
                    "events",
                    "window_us",
                    "delay_us",
                    "contrast_gain",
                    "ill_posed",
                )
            )
        )

    def __getitem__(self, index: slice | np.ndarray) -> Estimates:
        return Estimates(
            self.t_us[index],
            self.omega[index],
            self.events[index],
            self.window_us[index],
            self.delay_us[index],
            self.contrast_gain[index],
            self.ill_posed[index],
        )


@runtime_checkable
class GyroEstimator(Protocol):
    """Turns time-ordered event batches into angular-velocity estimates (see the module).

    ``label`` names the method in summaries. ``reset(t0_us)`` starts a new stream whose output
    clock starts at ``t0_us`` (None: the first event's whole millisecond); ``update(events)``
    returns the estimates the batch completes; ``finish(t_end_us)`` those still due up to the
    end of the stream (exclusive).
    """

    label: str

    def reset(self, t0_us: int | None = None) -> None: ...

    def update(self, events: EventArray) -> Estimates: ...

    def finish(self, t_end_us: int) -> Estimates: ...


def output_times(t0_us: int, rate_hz: float, done: int, upto_us: int) -> np.ndarray:
    """The fixed-rate output clock: times ``t0 + k / rate`` (µs, int64) for k = done+1, ...
    while ``<= upto_us``."""
    period = 1e6 / rate_hz
    last = int(np.floor((upto_us - t0_us) / period + 1e-9))
    k = np.arange(done + 1, last + 1, dtype=np.float64)
    return (t0_us + np.rint(k * period)).astype(np.int64)
