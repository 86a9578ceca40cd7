"""The spiking network on the event clock (:mod:`spikegyro.events.clock`), streaming.

:class:`ClockedPredictor` wraps a 1 ms :class:`~spikegyro.stream.predict.Predictor` (the exact
event-driven stream or the batched torch path): each closed step becomes one of the wrapped
predictor's 1 ms bins, and its output is turned into rad/s by the step's real duration and
stamped at the step's real end. :class:`RowHolder` turns those irregular estimates into rows on
a fixed grid (every 1 ms by default), each holding the latest estimate completed by its time,
with the step's length and the estimate's age, so that a file shows the latency.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Protocol

import numpy as np

from spikegyro.events.clock import STEP_US, Clock, EventClock, step_rates, virtual_times
from spikegyro.events.core import EventArray
from spikegyro.stream.estimator import Estimates


class _Bins(Protocol):
    steps: int
    label: str

    def push(self, events: EventArray) -> tuple[np.ndarray, np.ndarray]: ...

    def finish(self, t_end_us: int) -> tuple[np.ndarray, np.ndarray]: ...


_NONE = (np.zeros(0, np.int64), np.zeros((0, 3)))


class ClockedPredictor:
    """A 1 ms predictor run on the event clock: ``push``/``finish`` return ``(t_us, ω rad/s)``
    of the steps closed so far, stamped at each step's real end; ``step_us`` and ``counts``
    hold the length (µs) and events of those steps, for the last call.

    Args:
        inner: a predictor whose bins start at virtual time 0 (one per step).
        clock: an event clock.
        t0_us: where the first step begins, µs.
    """

    def __init__(self, inner: _Bins, clock: Clock, t0_us: int) -> None:
        self.inner = inner
        self._clock = EventClock(clock, t0_us)
        self.label = f"{inner.label}; {clock.label}"
        self.steps = 0
        self._pending: list[EventArray] = []
        self.step_us = np.zeros(0, np.int64)
        self.counts = np.zeros(0, np.int64)
        self._ended_us: int | None = None

    def push(self, events: EventArray) -> tuple[np.ndarray, np.ndarray]:
        if len(events):
            self._pending.append(events)
        begin = self._clock.begin_us
        return self._run(begin, *self._clock.push(events.t))

    def finish(self, t_end_us: int) -> tuple[np.ndarray, np.ndarray]:
        """Close the steps that end before ``t_end_us`` (exclusive, the stream's end)."""
        self._ended_us = int(t_end_us)
        begin = self._clock.begin_us
        return self._run(begin, *self._clock.finish(int(t_end_us) - 1))

    def _run(
        self, begin: int, ends: np.ndarray, counts: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        self.step_us = np.diff(np.concatenate([[begin], ends])).astype(np.int64)
        self.counts = counts
        if not len(ends):
            return _NONE
        total = int(counts.sum())
        first = _NONE[1]
        if total:
            ev = EventArray.concatenate(self._pending)
            now, rest = ev[:total], ev[total:]
            self._pending = [rest] if len(rest) else []
            vt = virtual_times(now.t, ends, np.cumsum(counts), begin) + self.steps * STEP_US
            first = self.inner.push(replace(now, t=vt))[1]
        last = self.inner.finish((self.steps + len(ends)) * STEP_US)[1]
        omega = np.concatenate([first, last]).reshape(-1, 3)
        self.steps += len(ends)
        return ends.astype(np.int64), omega * step_rates(ends, begin)[:, None]

    @property
    def settled_us(self) -> int:
        """Every step ending at or before this time (µs) has been returned (at the stream's
        end, its end: no event can come at or after it)."""
        return self._clock.settled_us if self._ended_us is None else self._ended_us


class RowHolder:
    """Estimates on a fixed grid from irregular steps: the row at time g holds the latest step
    that ended at or before g, with that step's length (``window_us``), events and age
    (``delay_us``: g minus the step's end). Rows come out once no later step can end before
    them, so they do not depend on how the stream was cut into chunks.

    Args:
        t0_us: the stream's start; rows at ``t0 + k * every_us``, k = 1, 2, ...
        every_us: the grid's spacing, µs (1 ms: one row per millisecond).
    """

    def __init__(self, t0_us: int, every_us: int = STEP_US) -> None:
        self.every_us = int(every_us)
        self._next_us = int(t0_us) + self.every_us
        self._last: tuple[np.ndarray, ...] | None = None

    def rows(
        self, ends_us: np.ndarray, omega: np.ndarray, step_us: np.ndarray, counts: np.ndarray,
        settled_us: int,
    ) -> Estimates:  # fmt: skip
        """The rows up to ``settled_us`` given the steps closed since the last call."""
        steps = (np.asarray(ends_us, np.int64), np.asarray(omega).reshape(-1, 3),
                 np.asarray(step_us, np.int64), np.asarray(counts, np.int64))  # fmt: skip
        if self._last is not None:
            pairs = zip(self._last, steps, strict=True)
            steps = tuple(np.concatenate([a[-1:], b]) for a, b in pairs)
        if len(steps[0]):
            self._last = steps
        grid = np.arange(self._next_us, int(settled_us) + 1, self.every_us, dtype=np.int64)
        if not len(grid):
            return Estimates.empty()
        self._next_us = int(grid[-1]) + self.every_us
        which = np.searchsorted(steps[0], grid, side="right") - 1
        grid, which = grid[which >= 0], which[which >= 0]
        ends, w, span, n = (a[which] for a in steps)
        return Estimates(
            grid, w, events=n, window_us=span.astype(np.float64),
            delay_us=(grid - ends).astype(np.float64),
        )  # fmt: skip


def clocked_per_ms(
    predictor: ClockedPredictor, events: EventArray, t_start_us: int, num_ms: int
) -> np.ndarray:
    """ω (rad/s, (num_ms, 3)) at the end of each millisecond of ``[t_start, t_start + num_ms
    ms)`` from a fresh clocked predictor fed ``events`` (on the model's grid): each holds the
    latest step that ended by then, 0 before the first."""
    end_us = int(t_start_us) + num_ms * STEP_US
    ends, omega = predictor.push(events)
    more_ends, more = predictor.finish(end_us)
    grid = int(t_start_us) + STEP_US * np.arange(1, num_ms + 1)
    return hold_on_grid(np.concatenate([ends, more_ends]), np.concatenate([omega, more]), grid)


def hold_on_grid(ends_us: np.ndarray, omega: np.ndarray, grid_us: np.ndarray) -> np.ndarray:
    """At each time of ``grid_us``, the latest of the estimates ``omega`` (K, 3) stamped
    ``ends_us`` (sorted, µs) at or before it; 0 before the first. (len(grid), 3)."""
    which = np.searchsorted(ends_us, grid_us, side="right") - 1
    out = np.zeros((len(grid_us), 3))
    out[which >= 0] = np.asarray(omega).reshape(-1, 3)[which[which >= 0]]
    return out
