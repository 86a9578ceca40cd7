"""What the commands that stream an event file share (``predict``, ``baseline cmax`` and
``calibrate-imu``): the event file and output options, the sensor and gyro options read into
one :class:`StreamInputs`, and :func:`predict_stream` under a progress bar."""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from spikegyro.checks import sensor_option
from spikegyro.events.calib import Calibration, resolve_calibration
from spikegyro.events.imu import imu_rotation
from spikegyro.events.io import EVENT_FILE_HELP, gyro_frame
from spikegyro.stream.estimator import GyroEstimator
from spikegyro.stream.predict import StreamResult, check_span, predict_stream, span_seconds

EVENTS = typer.Argument(..., help=EVENT_FILE_HELP)
"""The event file to stream (any format :mod:`spikegyro.events.io` reads)."""

PREDICTIONS_OUT = typer.Option(Path("pred.csv"), "--out", "-o", help="Output .csv or .h5.")
"""``--out FILE``: the prediction file (:mod:`spikegyro.stream.writer`)."""


@dataclass(frozen=True)
class StreamInputs:
    """The sensor and gyro options, checked.

    Attributes:
        calibration: the sensor's calibration (``--calib``, ``--intrinsics`` or an ECD folder's
            own), or None.
        sensor: (width, height) px for files that do not say, or None.
        gyro_rotation: R with ω_camera = R · ω_gyro (``--imu-to-camera``, or the known rotation
            of a camera file's IMU), or None (the gyro is used as it is).
        notes: lines to tell the user (the calibration file used, the gyro's frame).
    """

    calibration: Calibration | None
    sensor: tuple[int, int] | None
    gyro_rotation: np.ndarray | None
    notes: tuple[str, ...]


def stream_inputs(
    events: Path,
    calib: Path | None,
    intrinsics: tuple[float, float, float, float] | None,
    gyro: Path | None,
    imu_to_camera: str | None,
    width: int | None,
    height: int | None,
    start_s: float = 0.0,
    end_s: float | None = None,
) -> StreamInputs:
    """Check and read the options every streaming command has (``start_s``, ``end_s``: the
    span, s after the first event); raises :class:`~spikegyro.errors.InputError` before anything
    is written."""
    check_span(start_s, end_s)
    calibration, calib_file = resolve_calibration(events, calib, intrinsics)
    notes = [] if calib_file is None else [f"using the calibration {calib_file}"]
    sensor = sensor_option(width, height)
    frame = gyro_frame(gyro, imu_to_camera) if gyro is not None else None
    if frame is not None and frame.message:
        notes.append(("warning: " if frame.warning else "") + frame.message)
    if frame is not None:
        rotation = frame.rotation
    else:  # checked without a gyro too: a live camera's own IMU is rotated by it
        rotation = imu_rotation(imu_to_camera) if imu_to_camera else None
    return StreamInputs(calibration, sensor, rotation, tuple(notes))


def print_lines(console: Console, lines: Iterable[str]) -> None:
    """Each line on the console (stderr: stdout stays for the values a command prints)."""
    for line in lines:
        console.print(line)


def stream_with_progress(
    console: Console,
    label: str,
    events: str | os.PathLike,
    estimator: GyroEstimator,
    out: str | os.PathLike,
    *,
    sensor: tuple[int, int] | None = None,
    start_s: float = 0.0,
    end_s: float | None = None,
    **kwargs: Any,
) -> StreamResult:
    """:func:`predict_stream` of ``estimator`` under a transient progress bar named ``label``:
    seconds of events done (of the span, where the file says) and the real-time factor.
    ``kwargs`` go to :func:`predict_stream` (``gyro_path``, ``gyro_rotation``, ``plot``)."""
    total_s = span_seconds(events, start_s, end_s)
    columns = [
        TextColumn(f"[bold]{label}"),
        BarColumn(),
        TextColumn("{task.completed:.1f}/{task.fields[total_text]} s of events"),
        TextColumn("[cyan]{task.fields[rtf]}× real time"),
        TimeElapsedColumn(),
    ]
    with Progress(*columns, console=console, transient=True) as progress:
        total_text = f"{total_s:.1f}" if total_s else "?"
        task = progress.add_task(label, total=total_s, total_text=total_text, rtf="-")

        def update(done_s: float, wall_s: float) -> None:
            rtf = f"{done_s / wall_s:.1f}" if wall_s > 0 else "-"
            progress.update(task, completed=done_s, rtf=rtf)

        return predict_stream(
            events, estimator, None, out, sensor=sensor, start_s=start_s, end_s=end_s,
            on_progress=update, **kwargs,
        )  # fmt: skip
