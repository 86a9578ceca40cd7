"""Contrast-maximization estimates as series: over a stream in memory, per millisecond, and
over the evaluation's windows (the engine behind ``spikegyro evaluate --model cmax`` on
simulated data)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from spikegyro.cmax.config import CMaxConfig, Progress
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.problem import Intrinsics
from spikegyro.cmax.windows import WindowPolicy
from spikegyro.events.core import EventArray
from spikegyro.events.windows import BIN_US, series_per_window


def predict_stream(
    events: EventArray,
    camera: Intrinsics | None = None,
    config: CMaxConfig | None = None,
    *,
    t_first_us: int | None = None,
    t_end_us: int | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Causal estimates over a stream in memory (the engine of ``spikegyro predict --method
    cmax``), one every ``1 / config.rate_hz`` s.

    Args:
        events: the event stream, on the sensor's pixels.
        camera: the sensor's intrinsics or ``Calibration``; default :func:`default_camera`.
        config: estimator settings (adaptive causal windows at 100 Hz by default).
        t_first_us: the output clock's origin (estimates at ``t_first + k / rate``, k >= 1);
            default the first event's whole millisecond.
        t_end_us: no estimates after this time, µs (default: the last event).
        progress: optional callable ``progress(done, total)`` called after each batch.

    Returns:
        ``(t_us, omega)``: each estimate's time (int64 µs; it uses events up to it) and its ω
        (K, 3) rad/s.
    """
    estimator = CMaxEstimator(camera, config, t0_us=t_first_us)
    est = estimator.run(events, t_end_us, progress)
    return est.t_us, est.omega


def per_ms(t_us: np.ndarray, omega: np.ndarray, times_us: np.ndarray) -> np.ndarray:
    """Estimates at reference times ``t_us`` linearly interpolated onto ``times_us`` (µs).

    Constant beyond the first and last estimates; zeros when there is none.
    """
    if len(t_us) == 0:
        return np.zeros((len(times_us), 3))
    return np.column_stack([np.interp(times_us, t_us, omega[:, k]) for k in range(3)])


def hold_per_ms(t_us: np.ndarray, omega: np.ndarray, t_start_us: int, num_steps: int) -> np.ndarray:
    """Per-ms predictions (num_steps, 3): each step holds the latest estimate made by its end.

    Step k is the bin ``[t_start + k ms, t_start + (k + 1) ms)``; it takes the last estimate with
    ``t_us <= t_start + (k + 1) ms`` (zeros before the first estimate).
    """
    ends = t_start_us + BIN_US * (np.arange(num_steps, dtype=np.int64) + 1)
    index = np.searchsorted(t_us, ends, side="right") - 1
    held = np.zeros((num_steps, 3))
    held[index >= 0] = omega[index[index >= 0]]
    return held


SIMULATED_CONFIG = CMaxConfig(
    rate_hz=200.0, window=WindowPolicy(fixed_ms=30.0), search_in_line=True
)
"""Causal 30 ms windows every 5 ms: the networks' setting in ``spikegyro evaluate``. Searches
run in line: a window of 100 ms ends before a search beside the estimates would be taken up."""


def predict_windows(
    windows: Sequence[Any],
    config: CMaxConfig | None = None,
    camera: Intrinsics | None = None,
    progress: Progress | None = None,
    first_step: int = 0,
) -> np.ndarray:
    """Per-ms ω (n, T, 3) rad/s for ``spikegyro.train.data.Window`` objects (evaluation's API).

    Each window is streamed on its own (no events from outside it, as for the networks), with
    estimates every ``1 / config.rate_hz`` s from its start, each from the events before it
    (fewer at the window's start), held per ms as in :func:`hold_per_ms`. Steps before
    ``first_step`` are zero; pass the metrics' first step (50) to skip work that is not scored.

    Args:
        windows: objects with ``events`` (EventArray), ``omega`` (T, 3) and ``t_start_us``.
        config: estimator settings (default :data:`SIMULATED_CONFIG`).
        camera: pinhole intrinsics (default :func:`default_camera` of the sensor).
        progress: optional callable ``progress(done, total)`` called after each window.
        first_step: first 1 ms step that gets an estimate.
    """
    config = config or SIMULATED_CONFIG

    def held(batch: Sequence[Any]) -> np.ndarray:
        (window,) = batch  # one at a time: each window is streamed on its own
        steps = int(np.asarray(window.omega).shape[0])
        t0 = int(window.t_start_us)
        t_us, omega = predict_stream(
            window.events, camera, config, t_first_us=t0, t_end_us=t0 + BIN_US * steps
        )
        keep = t_us > t0 + BIN_US * first_step
        series = hold_per_ms(t_us[keep], omega[keep], t0, steps)
        series[:first_step] = 0.0
        return series[None]

    num_steps = int(np.asarray(windows[0].omega).shape[0]) if len(windows) else 0
    done = None if progress is None else lambda n: progress(n, len(windows))
    return series_per_window(held, windows, num_steps, progress=done)
