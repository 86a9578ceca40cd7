"""The network's clock: how an event stream is cut into the steps a spiking network runs.

A spiking network sees what moves within its memory, and its kernels count steps. With the
paper's clock a step is 1 ms, so at hand-held speeds (5-100 deg/s) an edge moves less than a
pixel within the few steps the network remembers. The *event clock* lets the motion set the
pace: a step closes once it holds ``events_per_step`` events, but not before ``min_step_us``
has passed since the previous step closed, and at the latest after ``max_step_us``.

Step k spans ``(end[k-1], end[k]]`` (microseconds; ``end[-1]`` is the stream's start, whose
own time belongs to step 0). With events, the step's end is the time of its N-th event (every
event sharing that timestamp joins it); clamped by the minimum or the maximum, the end is that
bound. The network runs in its own time, one virtual millisecond per step: an event of step k
is given the virtual time ``k ms`` plus its place within the step, and the network's output for
the step is the rotation over the step per virtual millisecond, so that

    ω (rad/s) = output × 1 ms / Δ_k,       Δ_k = end[k] - end[k-1].

Its training label is the mean ω over the step times ``Δ_k / 1 ms``. Replaying a recording k
times faster gives the same steps (where no bound binds) and k times the ω.

Pure NumPy: the training windows, evaluation and the streaming runtime share it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from spikegyro.errors import InputError

STEP_US = 1000
"""One step of the network's own time (a virtual millisecond), µs."""


@dataclass(frozen=True)
class Clock:
    """How the network's steps follow the events.

    Attributes:
        events_per_step: a step closes after this many events; 0: the paper's clock, fixed
            1 ms steps.
        min_step_us: shortest step, µs (a burst of events does not make steps shorter).
        max_step_us: longest step, µs (a still scene still gets estimates this often).
    """

    events_per_step: int = 0
    min_step_us: int = 1000
    max_step_us: int = 20000

    def __post_init__(self) -> None:
        if self.events_per_step < 0:
            raise InputError(f"clock: {self.events_per_step} events per step; use 0 or more.")
        if not 1 <= self.min_step_us <= self.max_step_us:
            raise InputError(
                f"clock: steps of {self.min_step_us}-{self.max_step_us} µs; the shortest must "
                "be at least 1 µs and at most the longest."
            )

    @property
    def is_paper(self) -> bool:
        """Fixed 1 ms steps (the paper's clock)."""
        return self.events_per_step == 0

    @property
    def label(self) -> str:
        if self.is_paper:
            return "1 ms steps"
        return (
            f"{self.events_per_step} events per step "
            f"({self.min_step_us / 1000:g}-{self.max_step_us / 1000:g} ms)"
        )

    @property
    def text(self) -> str:
        """The clock as :meth:`parse` reads it."""
        if self.is_paper:
            return "paper"
        bounds = f"{self.min_step_us / 1000:g}-{self.max_step_us / 1000:g}"
        return f"events:{self.events_per_step}:{bounds}"

    def as_dict(self) -> dict[str, int]:
        return {
            "events_per_step": self.events_per_step,
            "min_step_us": self.min_step_us,
            "max_step_us": self.max_step_us,
        }

    @classmethod
    def from_dict(cls, spec: dict[str, Any] | None) -> Clock:
        """The clock a checkpoint's ``input["clock"]`` describes (None or absent: the paper's)."""
        if not spec:
            return cls()
        return cls(**{k: int(v) for k, v in spec.items() if k in cls.__dataclass_fields__})

    @classmethod
    def parse(cls, text: str) -> Clock:
        """``paper`` (1 ms steps) or ``events:N`` or ``events:N:MIN-MAX`` (bounds in ms)."""
        text = text.strip().lower()
        if text in ("paper", "time", "1ms"):
            return cls()
        match = re.fullmatch(r"events:(\d+)(?::([\d.]+)-([\d.]+))?", text)
        if not match or int(match.group(1)) < 1:
            raise InputError(
                f"--clock '{text}': use 'paper' (1 ms steps) or 'events:N' or "
                "'events:N:MIN-MAX' (N events per step, step length bounds in ms), "
                "e.g. events:500:1-20."
            )
        lo, hi = (
            (float(match.group(2)), float(match.group(3))) if match.group(2) else (1.0, 20.0)
        )
        return cls(int(match.group(1)), round(lo * 1000), round(hi * 1000))


def close_steps(
    t_us: np.ndarray, begin_us: int, clock: Clock, *, known_us: float = -np.inf,
    max_steps: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The steps that the events ``t_us`` complete, from ``begin_us`` on.

    Args:
        t_us: sorted event times, µs, none before ``begin_us``.
        begin_us: where the first step begins, µs.
        clock: the clock (events per step and bounds).
        known_us: every event up to this time (µs, inclusive) is in ``t_us``; a step whose end
            lies beyond the last event can only close by then (the end of a stream). Steps
            whose end the events after it could still change stay open.
        max_steps: stop after this many steps (None: all that are complete).

    Returns:
        ``(ends_us, cuts)``, int64 (K,): step k ends at ``ends_us[k]`` and holds the events
        ``t_us[cuts[k-1]:cuts[k]]`` (``cuts[-1]`` = 0).
    """
    t_us = np.asarray(t_us)
    n, count = len(t_us), clock.events_per_step
    last = float(t_us[-1]) if n else -np.inf
    ends: list[int] = []
    cuts: list[int] = []
    begin, first = int(begin_us), 0
    if clock.is_paper:
        raise ValueError("close_steps runs the event clock; the paper's steps are 1 ms bins")
    while max_steps is None or len(ends) < max_steps:
        if first + count - 1 < n:
            end = min(max(int(t_us[first + count - 1]), begin + clock.min_step_us),
                      begin + clock.max_step_us)  # fmt: skip
        else:
            end = begin + clock.max_step_us
        if not (last > end or known_us >= end):
            break
        first = int(np.searchsorted(t_us, end, side="right"))
        ends.append(end)
        cuts.append(first)
        begin = end
    return np.asarray(ends, np.int64), np.asarray(cuts, np.int64)


def step_begins(ends_us: np.ndarray, begin_us: int) -> np.ndarray:
    """The time each step starts from (the previous step's end; ``begin_us`` for the first)."""
    return np.concatenate([[begin_us], ends_us[:-1]]).astype(np.int64)


def virtual_times(
    t_us: np.ndarray, ends_us: np.ndarray, cuts: np.ndarray, begin_us: int
) -> np.ndarray:
    """Each event's time in the network's own clock, µs: step k is ``[k ms, (k+1) ms)``, and an
    event's place within it is its place within the step's real span (order is kept).

    ``t_us[: cuts[-1]]`` are the events of the steps; (cuts[-1],) int64.
    """
    k = len(ends_us)
    if not k:
        return np.zeros(0, np.int64)
    sizes = np.diff(np.concatenate([[0], cuts]))
    step = np.repeat(np.arange(k, dtype=np.int64), sizes)
    begins = step_begins(ends_us, begin_us)
    span = np.maximum(ends_us - begins, 1).astype(np.float64)
    frac = (np.asarray(t_us[: cuts[-1]], np.float64) - begins[step]) / span[step]
    within = np.clip(np.floor(frac * STEP_US), 0, STEP_US - 1).astype(np.int64)
    return step * STEP_US + within


def step_rates(ends_us: np.ndarray, begin_us: int) -> np.ndarray:
    """The factor from the network's output to rad/s for each step: ``1 ms / Δ_k`` (K,)."""
    durations = np.diff(np.concatenate([[begin_us], ends_us])).astype(np.float64)
    return STEP_US / np.maximum(durations, 1.0)


def integrate_rate(t_us: np.ndarray, omega: np.ndarray, at_us: np.ndarray) -> np.ndarray:
    """∫ ω dt from ``t_us[0]`` to each of ``at_us`` (rad, (len, 3)), ω linear between samples
    (exact for the linearly interpolated trace); held constant outside the samples."""
    t = np.asarray(t_us, np.float64)
    w = np.asarray(omega, np.float64)
    h = np.diff(t) * 1e-6
    area = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (w[1:] + w[:-1]) * h[:, None], 0)])
    at = np.asarray(at_us, np.float64)
    i = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 1)
    dt = (at - t[i]) * 1e-6
    j = np.minimum(i + 1, len(t) - 1)
    slope = np.where(
        (j > i)[:, None], (w[j] - w[i]) / np.maximum(t[j] - t[i], 1e-9)[:, None] * 1e6, 0.0
    )
    # before the first sample ω is held, so only the linear term applies there
    inside = np.clip(dt, 0, None)[:, None]
    return area[i] + w[i] * dt[:, None] + 0.5 * slope * inside**2


def mean_rates(
    t_us: np.ndarray, omega: np.ndarray, begins_us: np.ndarray, ends_us: np.ndarray
) -> np.ndarray:
    """Mean ω (rad/s, (K, 3)) over each ``[begin, end]`` µs of a linearly interpolated trace."""
    begins_us = np.asarray(begins_us, np.float64)
    ends_us = np.asarray(ends_us, np.float64)
    area = integrate_rate(t_us, omega, ends_us) - integrate_rate(t_us, omega, begins_us)
    return area / (np.maximum(ends_us - begins_us, 1.0) * 1e-6)[:, None]


class EventClock:
    """The event clock over a stream: feed time-ordered event times, get the steps they close.

    ``push(t_us)`` returns ``(ends_us, counts)`` of the newly closed steps (counts: events per
    step, in the order pushed); ``finish(end_us)`` closes the steps that end by ``end_us``
    (inclusive). The caller keeps the events themselves: the steps take them in order.
    """

    def __init__(self, clock: Clock, begin_us: int) -> None:
        if clock.is_paper:
            raise ValueError("EventClock runs the event clock; the paper's steps are 1 ms bins")
        self.clock = clock
        self.begin_us = int(begin_us)
        self._pending = np.zeros(0, np.int64)
        self._seen_us = float(begin_us)
        self._known_us = -np.inf

    @property
    def settled_us(self) -> int:
        """Every step that ends at or before this time (µs) is closed: the open step cannot end
        before its minimum length, nor before the next event (unless it reaches its maximum)."""
        if self._known_us > -np.inf:
            return int(self._known_us)
        clock, begin = self.clock, self.begin_us
        earliest = min(begin + clock.max_step_us, max(begin + clock.min_step_us, self._seen_us))
        return int(earliest) - 1

    def push(self, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_us = np.asarray(t_us, np.int64)
        if len(t_us):
            self._seen_us = max(self._seen_us, float(t_us[-1]))
        self._pending = np.concatenate([self._pending, t_us])
        return self._close(-np.inf)

    def finish(self, end_us: int) -> tuple[np.ndarray, np.ndarray]:
        self._known_us = float(end_us)
        return self._close(float(end_us))

    def _close(self, known_us: float) -> tuple[np.ndarray, np.ndarray]:
        ends, cuts = close_steps(self._pending, self.begin_us, self.clock, known_us=known_us)
        if not len(ends):
            return ends, cuts
        counts = np.diff(np.concatenate([[0], cuts]))
        self._pending = self._pending[cuts[-1] :]
        self.begin_us = int(ends[-1])
        return ends, counts
