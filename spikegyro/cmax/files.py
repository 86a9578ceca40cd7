"""Contrast maximization on an event file or a live stream: the intrinsics to use, a live
estimator for it, one estimate from all of a file's events."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.problem import Intrinsics, camera_from_attrs, default_camera
from spikegyro.cmax.search import estimate_whole
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration
from spikegyro.events.core import EventArray
from spikegyro.events.io import detect_format, iter_event_chunks, read_hdf5_attrs, read_recording
from spikegyro.events.windows import BIN_US


def camera_for_file(
    path: str | os.PathLike,
    calibration: Calibration | None = None,
    sensor: tuple[int, int] | None = None,
) -> tuple[Intrinsics, str]:
    """The intrinsics to run contrast maximization on ``path`` with, and a line saying where
    they come from: the user's calibration, the file's own (a spikegyro sequence file's
    ``fx fy cx cy``), or, where neither exists, the simulator's pinhole (f = 200 px at 240 px
    wide, principal point at the centre), which a real camera only matches by chance."""
    first = next((c for c in iter_event_chunks(path, sensor=sensor, chunk_events=1000)), None)
    if first is None or not len(first):
        raise InputError(f"{path}: the file holds no events.")
    width, height = first.sensor_size
    if calibration is not None:
        return calibration, _given(calibration)
    attrs = read_hdf5_attrs(path) if detect_format(path) == "hdf5" else {}
    camera = camera_from_attrs(attrs, width, height)
    if "fx" in attrs:
        return camera, (
            f"intrinsics from the file: fx {camera.fx:g}, fy {camera.fy:g}, cx {camera.cx:g}, "
            f"cy {camera.cy:g} px"
        )
    return camera, _assumed(Path(path).name, camera)


def _given(calibration: Calibration) -> str:
    """The line saying that the user's calibration is used."""
    kind = "pinhole" if calibration.is_pinhole else "with lens distortion"
    return (
        f"intrinsics fx {calibration.fx:g}, fy {calibration.fy:g}, cx {calibration.cx:g}, "
        f"cy {calibration.cy:g} px ({kind}), as given"
    )


def _assumed(name: str, camera: Intrinsics) -> str:
    """The warning that ``name`` brings no calibration and ``camera`` is assumed."""
    return (
        f"warning: {name} brings no calibration; assuming a {camera.width}x{camera.height} "
        f"pinhole with fx = fy = {camera.fx:g} px and the principal point at ({camera.cx:g}, "
        f"{camera.cy:g}), no distortion. Angular speeds scale with the focal length: pass "
        "--intrinsics fx fy cx cy or --calib FILE."
    )


def cmax_estimator_for_file(
    path: str | os.PathLike,
    calibration: Calibration | None = None,
    sensor: tuple[int, int] | None = None,
    rate_hz: float | None = None,
    window_ms: float | None = None,
    config: CMaxConfig | None = None,
) -> tuple[CMaxEstimator, str]:
    """A :class:`CMaxEstimator` for an event file (intrinsics by :func:`camera_for_file`),
    with ``rate_hz`` (None: the config's) and a fixed ``window_ms`` (None: adaptive), and the
    line saying which intrinsics it uses."""
    camera, note = camera_for_file(path, calibration, sensor)
    return CMaxEstimator(camera, _with_options(config, rate_hz, window_ms)), note


def cmax_estimator_for_stream(
    calibration: Calibration | None = None,
    rate_hz: float | None = None,
    window_ms: float | None = None,
) -> CMaxEstimator:
    """A :class:`CMaxEstimator` for a live stream, as :func:`cmax_estimator_for_file`: the
    calibration given, else the default pinhole of the first batch's sensor
    (:func:`stream_camera_note` says which). Its compiled code is loaded here, by a throwaway
    run on random events, so that the stream does not queue up while it loads (about 2 s)."""
    config = _with_options(None, rate_hz, window_ms)
    rng = np.random.default_rng(0)
    n = 20_000
    t = np.sort(rng.integers(0, 60_000, n))
    xy = rng.integers(0, 180, (2, n))
    warm = EventArray.from_arrays(xy[0], xy[1], t, rng.integers(0, 2, n), 240, 180)
    CMaxEstimator(None, config).run(warm)
    return CMaxEstimator(calibration, config)


def stream_camera_note(name: str, sensor: tuple[int, int], calibration: Calibration | None) -> str:
    """The line saying which intrinsics :func:`cmax_estimator_for_stream` uses on ``sensor``."""
    if calibration is not None:
        return _given(calibration)
    return _assumed(name, default_camera(*sensor))


def _with_options(
    config: CMaxConfig | None, rate_hz: float | None, window_ms: float | None
) -> CMaxConfig:
    """``config`` (None: the default) with ``--rate-hz`` and a fixed ``--window-ms`` if given."""
    config = config or CMaxConfig()
    if rate_hz is not None:
        config = replace(config, rate_hz=float(rate_hz))
    if window_ms is not None:
        config = replace(config, window=replace(config.window, fixed_ms=float(window_ms)))
    return config


@dataclass(frozen=True)
class WholeEstimate:
    """One estimate from every event of a span (``baseline cmax --whole``).

    Attributes:
        t_us: its time, the last event's, µs.
        omega: ω (3,) rad/s.
        events: events it used.
        duration_us: the events' span, µs.
        note: where the intrinsics come from (:func:`camera_for_file`).
    """

    t_us: int
    omega: np.ndarray
    events: int
    duration_us: int
    note: str


def estimate_whole_file(
    path: str | os.PathLike,
    calibration: Calibration | None = None,
    sensor: tuple[int, int] | None = None,
    start_s: float = 0.0,
    end_s: float | None = None,
) -> WholeEstimate:
    """One estimate from all events of ``path`` (read into memory) between ``start_s`` and
    ``end_s`` (s after the first event's whole millisecond; None: the last event), stamped at
    the last of them."""
    rec = read_recording(path, sensor=sensor)
    if not len(rec.events):
        raise InputError(f"{path}: the file holds no events.")
    camera, note = camera_for_file(path, calibration, sensor)
    t0 = int(rec.events.t[0]) // BIN_US * BIN_US
    t_end = int(rec.events.t[-1]) + 1 if end_s is None else t0 + round(end_s * 1e6)
    ev = rec.events.slice_time(t0 + round(start_s * 1e6), t_end)
    if not len(ev):
        raise InputError(f"{path}: no events between --start and --end.")
    return WholeEstimate(int(ev.t[-1]), estimate_whole(ev, camera), len(ev), ev.duration_us, note)
