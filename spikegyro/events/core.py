"""Event arrays and gyro traces: plain NumPy containers with validation and cheap time slicing.

Conventions (see README): x, y are 0-based pixel coordinates (x right, y down), t is in
microseconds (int64), p is 0 for OFF and 1 for ON; events are sorted by t. Angular velocity is
in rad/s, expressed in the camera frame (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from spikegyro.errors import InputError


@dataclass(frozen=True)
class EventArray:
    """A time-sorted stream of events from a ``width`` x ``height`` sensor.

    Attributes:
        x: column of each event, pixels, int16, in [0, width).
        y: row of each event, pixels, int16, in [0, height).
        t: timestamp of each event, microseconds, int64, non-decreasing.
        p: polarity of each event, uint8, 0 = OFF (darker), 1 = ON (brighter).
        width: sensor width in pixels.
        height: sensor height in pixels.
    """

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray
    width: int
    height: int

    @classmethod
    def from_arrays(
        cls,
        x: Any,
        y: Any,
        t: Any,
        p: Any,
        width: int,
        height: int,
        *,
        source: str = "events",
        validate: bool = True,
    ) -> EventArray:
        """Build an event array, casting to the canonical dtypes and (by default) validating.

        ``p`` may be given as {0, 1} or {-1, +1}; both map to 0 = OFF, 1 = ON.
        """
        p = np.asarray(p)
        if p.size and p.min() < 0:
            p = p > 0
        events = cls(
            x=np.asarray(x).astype(np.int16, copy=False),
            y=np.asarray(y).astype(np.int16, copy=False),
            t=np.asarray(t).astype(np.int64, copy=False),
            p=p.astype(np.uint8, copy=False),
            width=int(width),
            height=int(height),
        )
        if validate:
            events.validate(source)
        return events

    @classmethod
    def empty(cls, width: int, height: int) -> EventArray:
        """An event array with no events."""
        return cls.from_arrays([], [], [], [], width, height, validate=False)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def sensor_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    @property
    def duration_us(self) -> int:
        """Time from the first to the last event, microseconds (0 when fewer than two events)."""
        return int(self.t[-1] - self.t[0]) if len(self) > 1 else 0

    def validate(self, source: str = "events") -> None:
        """Raise :class:`InputError` naming ``source`` if the events break the conventions."""
        n = len(self)
        if not (self.x.shape == self.y.shape == self.p.shape == (n,)):
            raise InputError(
                f"{source}: x, y, t, p must be 1-D arrays of equal length, got shapes "
                f"{self.x.shape}, {self.y.shape}, {self.t.shape}, {self.p.shape}."
            )
        if self.width <= 0 or self.height <= 0:
            raise InputError(
                f"{source}: sensor size must be positive, got {self.width}x{self.height}."
            )
        if n == 0:
            return
        bad = (self.x < 0) | (self.x >= self.width) | (self.y < 0) | (self.y >= self.height)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(
                f"{source}: {int(bad.sum())} events lie outside the {self.width}x{self.height} "
                f"sensor (first: index {i}, x={self.x[i]}, y={self.y[i]}); pass the right "
                "sensor size or crop the events."
            )
        if (self.p > 1).any():
            raise InputError(f"{source}: polarity must be 0 (OFF) or 1 (ON).")
        steps = np.diff(self.t)
        if (steps < 0).any():
            i = int(np.argmax(steps < 0))
            raise InputError(
                f"{source}: timestamps are not sorted (t[{i + 1}]={self.t[i + 1]} us < "
                f"t[{i}]={self.t[i]} us); sort the events by time first."
            )

    def slice_time(self, t_start_us: int, t_end_us: int) -> EventArray:
        """The events with ``t_start_us <= t < t_end_us`` (a view; binary search, O(log n))."""
        i0, i1 = np.searchsorted(self.t, [t_start_us, t_end_us], side="left")
        return self[int(i0) : int(i1)]

    def __getitem__(self, index: slice | np.ndarray) -> EventArray:
        return replace(self, x=self.x[index], y=self.y[index], t=self.t[index], p=self.p[index])

    def shift_time(self, offset_us: int) -> EventArray:
        """The same events with ``offset_us`` added to every timestamp."""
        return replace(self, t=self.t + np.int64(offset_us))

    def rescale(self, factor: float) -> EventArray:
        """Map events onto a sensor ``factor`` times the size (x' = floor(x * factor)).

        Used to feed a network trained at reduced resolution; several events may land on
        the same output pixel.
        """
        width = max(1, round(self.width * factor))
        height = max(1, round(self.height * factor))
        x = np.minimum(np.floor(self.x * factor), width - 1)
        y = np.minimum(np.floor(self.y * factor), height - 1)
        return replace(
            self,
            x=x.astype(np.int16),
            y=y.astype(np.int16),
            width=width,
            height=height,
        )

    @staticmethod
    def concatenate(parts: list[EventArray]) -> EventArray:
        """Join time-ordered chunks from the same sensor into one array."""
        if not parts:
            raise ValueError("concatenate needs at least one event array")
        first = parts[0]
        return replace(
            first,
            x=np.concatenate([e.x for e in parts]),
            y=np.concatenate([e.y for e in parts]),
            t=np.concatenate([e.t for e in parts]),
            p=np.concatenate([e.p for e in parts]),
        )


@dataclass(frozen=True)
class GyroTrace:
    """Angular velocity samples.

    Attributes:
        t: sample times, microseconds, int64, increasing.
        omega: (K, 3) angular velocity (omega_x, omega_y, omega_z) in rad/s, camera frame.
    """

    t: np.ndarray
    omega: np.ndarray

    @classmethod
    def from_arrays(cls, t: Any, omega: Any, *, source: str = "gyro") -> GyroTrace:
        """Build a trace, casting dtypes and checking shapes and time order."""
        trace = cls(
            t=np.asarray(t).astype(np.int64, copy=False),
            omega=np.asarray(omega, dtype=np.float64).reshape(-1, 3),
        )
        if trace.t.shape != (trace.omega.shape[0],):
            raise InputError(
                f"{source}: {trace.t.shape[0]} timestamps but {trace.omega.shape[0]} "
                "angular-velocity rows; each sample needs t, wx, wy, wz."
            )
        if trace.t.size > 1 and (np.diff(trace.t) < 0).any():
            raise InputError(f"{source}: gyro timestamps are not sorted; sort them by time.")
        return trace

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def interpolate(self, t_us: np.ndarray) -> np.ndarray:
        """Linearly interpolated omega (rad/s) at times ``t_us`` (microseconds), shape (len, 3)."""
        t_us = np.asarray(t_us, dtype=np.float64)
        return np.stack(
            [np.interp(t_us, self.t.astype(np.float64), self.omega[:, k]) for k in range(3)],
            axis=-1,
        )

    def slice_time(self, t_start_us: int, t_end_us: int) -> GyroTrace:
        """Samples with ``t_start_us <= t < t_end_us``."""
        i0, i1 = np.searchsorted(self.t, [t_start_us, t_end_us], side="left")
        return GyroTrace(t=self.t[i0:i1], omega=self.omega[i0:i1])


@dataclass(frozen=True)
class Recording:
    """Events plus optional ground-truth or measured angular velocity, and free-form metadata.

    ``attrs`` holds what our sequence files store as HDF5 attributes (intrinsics, contrast
    thresholds, scene, seed, ...); JSON-serialisable scalars, strings and short lists only.
    """

    events: EventArray
    gyro: GyroTrace | None = None
    attrs: dict[str, Any] = field(default_factory=dict)

    def slice_time(self, t_start_us: int, t_end_us: int) -> Recording:
        """Events and gyro samples in ``[t_start_us, t_end_us)``."""
        gyro = None if self.gyro is None else self.gyro.slice_time(t_start_us, t_end_us)
        return replace(self, events=self.events.slice_time(t_start_us, t_end_us), gyro=gyro)
