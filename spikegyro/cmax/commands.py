"""``spikegyro baseline cmax`` (contrast maximization on an event file: the offline engine of
``predict --method cmax --offline``, or with ``--live`` the live one) and ``spikegyro
calibrate-imu`` (the gyro's frame, bias and clock offset)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import typer
from rich.console import Console

from spikegyro import options
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.files import cmax_estimator_for_file, estimate_whole_file
from spikegyro.cmax.offline import offline_estimator_for_file
from spikegyro.cmax.windows import WindowPolicy
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration
from spikegyro.events.imu import ImuFit, fit_imu_to_camera, rotation_text
from spikegyro.events.io import read_gyro
from spikegyro.stream.console import (
    EVENTS,
    PREDICTIONS_OUT,
    print_lines,
    stream_inputs,
    stream_with_progress,
)
from spikegyro.stream.predict import summary_lines
from spikegyro.stream.writer import check_prediction_path, read_predictions, write_predictions

app = typer.Typer(
    help="Non-learned baselines that read event files like `spikegyro predict`.",
    no_args_is_help=True,
)

CALIB = typer.Option(
    None,
    "--calib",
    help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt; taken from an ECD "
    "folder by default); events are undistorted to rays with it.",
)
GYRO = typer.Option(
    None,
    "--gyro",
    help="Reference angular velocity (gyro/IMU text or a file with ground truth): adds it "
    "and the error to the output and prints metrics.",
)
RATE_HZ = typer.Option(
    CMaxConfig.rate_hz,
    "--rate-hz",
    min=0.0,
    help="Estimates per second of events; 0 (with --live): one per chunk of events read.",
)
LIVE = typer.Option(
    False,
    "--live",
    help="The live engine of `predict --method cmax` (each estimate from the events before it, "
    "in causal windows) instead of the offline one (centred windows).",
)
WINDOW_MS = typer.Option(
    None,
    "--window-ms",
    min=0.1,
    help="With --live: a fixed causal window of this many ms (else adaptive).",
)
WINDOW_EVENTS = typer.Option(
    None, "--window-events", min=100, help="With --live: a fixed window of the last N events."
)
WHOLE = typer.Option(
    False, "--whole", help="One estimate from all events between --start and --end."
)
MAX_EVENTS = typer.Option(
    None,
    "--max-events",
    min=100,
    help="With --live: events an estimate uses at most (larger windows are thinned evenly; "
    f"default {CMaxConfig.track_events:,}).",
)


@app.command("cmax")
def cmax_command(
    events: Path = EVENTS,
    calib: Path = CALIB,
    intrinsics: tuple[float, float, float, float] = options.INTRINSICS,
    gyro: Path = GYRO,
    imu_to_camera: str = options.IMU_TO_CAMERA,
    start: float = options.START,
    end: float = options.END,
    out: Path = PREDICTIONS_OUT,
    rate_hz: float = RATE_HZ,
    live: bool = LIVE,
    window_ms: float = WINDOW_MS,
    window_events: int = WINDOW_EVENTS,
    whole: bool = WHOLE,
    max_events: int = MAX_EVENTS,
    width: int = options.WIDTH,
    height: int = options.HEIGHT,
) -> None:
    """Contrast maximization (Gallego & Scaramuzza 2017), no training, as a baseline on a file.

    By default the offline engine of `predict --method cmax --offline`: each estimate, at
    --rate-hz, from the events around its time. --live: the live engine of `predict --method
    cmax` instead, each estimate from the events before it, in a window that adapts to the event
    rate and the motion (or is fixed by --window-ms or --window-events). Each row is its own
    estimate with its confidence. --whole gives one estimate from all events instead.
    """
    _check_engine_options(live, whole, rate_hz, window_ms, window_events, max_events)
    check_prediction_path(out)
    inputs = stream_inputs(
        events, calib, intrinsics, gyro, imu_to_camera, width, height, start, end
    )
    console = Console(stderr=True)
    print_lines(console, inputs.notes)
    if whole:
        _whole(console, events, inputs.calibration, inputs.sensor, start, end, out)
        return
    if live:
        window = WindowPolicy(fixed_ms=window_ms or 0.0, fixed_events=window_events or 0)
        config = CMaxConfig(rate_hz=rate_hz, window=window)
        if max_events is not None:
            config = replace(config, track_events=max_events)
        estimator, note = cmax_estimator_for_file(
            events, inputs.calibration, inputs.sensor, config=config
        )
    else:
        estimator, note = offline_estimator_for_file(
            events, inputs.calibration, inputs.sensor, rate_hz
        )
    console.print(note)
    result = stream_with_progress(
        console, "cmax", events, estimator, out, sensor=inputs.sensor, start_s=start, end_s=end,
        gyro_path=gyro, gyro_rotation=inputs.gyro_rotation,
    )  # fmt: skip
    print_lines(console, summary_lines(result, out))


def _check_engine_options(
    live: bool,
    whole: bool,
    rate_hz: float,
    window_ms: float | None,
    window_events: int | None,
    max_events: int | None,
) -> None:
    """The window options go with --live (one of --window-ms and --window-events), not with
    --whole; the offline engine needs a rate above 0."""
    if window_ms is not None and window_events is not None:
        raise InputError("--window-ms and --window-events: give one of them, not both.")
    given = [
        name
        for name, value in (
            ("--window-ms", window_ms),
            ("--window-events", window_events),
            ("--max-events", max_events),
        )
        if value is not None
    ]
    if given and (whole or not live):
        raise InputError(
            f"{given[0]} sets the live engine's windows: add --live (the offline engine and "
            "--whole size their own)."
        )
    if not live and not whole and rate_hz <= 0:
        raise InputError("--rate-hz 0 (one estimate per chunk read) needs --live.")


def _whole(
    console: Console,
    events: Path,
    calibration: Calibration | None,
    sensor: tuple[int, int] | None,
    start: float,
    end: float | None,
    out: Path,
) -> None:
    """``--whole``: one estimate from all events of the span, written to ``out`` and printed."""
    est = estimate_whole_file(events, calibration, sensor, start, end)
    console.print(est.note)
    write_predictions(out, np.array([est.t_us]), est.omega[None])
    console.print(
        f"one estimate from {est.events:,} events ({est.duration_us / 1000:.1f} ms), ω = "
        f"{np.array2string(np.degrees(est.omega), precision=1)} deg/s (tilt, pan, roll) -> {out}"
    )


RAW_GYRO = typer.Option(
    None,
    "--gyro",
    help="The raw gyro, in its IMU's axes (gyro/IMU text, or a camera file with an IMU); "
    "default: the event file's own IMU.",
)
PLAIN_CALIB = typer.Option(
    None, "--calib", help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt)."
)
MAX_OFFSET_MS = typer.Option(
    50.0, "--max-offset-ms", min=0.0, help="Clock offsets tried: within ± this many ms."
)


def calibrate_imu(
    events: Path = EVENTS,
    gyro: Path = RAW_GYRO,
    calib: Path = PLAIN_CALIB,
    intrinsics: tuple[float, float, float, float] = options.INTRINSICS,
    max_offset_ms: float = MAX_OFFSET_MS,
    start: float = options.START,
    end: float = options.END,
    width: int = options.WIDTH,
    height: int = options.HEIGHT,
) -> None:
    """The gyro's IMU-to-camera rotation, bias and clock offset, from a recording with events
    and gyro: contrast maximization's camera-frame ω, then a least-squares rotation plus bias
    at the best clock offset. Prints the --imu-to-camera value to use.
    """
    console = Console(stderr=True)
    inputs = stream_inputs(events, calib, intrinsics, None, None, width, height, start, end)
    trace = read_gyro(gyro if gyro is not None else events)
    estimator, note = cmax_estimator_for_file(events, inputs.calibration, inputs.sensor)
    console.print(note)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cmax.h5"
        result = stream_with_progress(
            console, "cmax", events, estimator, out, sensor=inputs.sensor, start_s=start,
            end_s=end,
        )  # fmt: skip
        est = read_predictions(out)
    good = est["ill_posed"] == 0
    if good.sum() < 10:
        raise InputError(
            f"{events}: only {int(good.sum())} well-posed estimates; calibration needs a recording "
            "with motion about several axes and enough events."
        )
    fit = fit_imu_to_camera(est["t_us"][good], est["omega"][good], trace, max_offset_ms * 1000)
    _print_fit(console, fit, result.estimates)


def _print_fit(console: Console, fit: ImuFit, estimates: int) -> None:
    """The fit, and a warning where the motion leaves the rotation undetermined."""
    text = rotation_text(fit.rotation)
    bias_cam = fit.rotation @ fit.bias
    console.print(
        f"fitted on {fit.samples:,} of {estimates:,} estimates: RMS residual "
        f"{np.degrees(fit.rms_rad_s):.2f} deg/s"
    )
    console.print(f"clock offset: {fit.offset_us / 1000:+.1f} ms (added to the gyro's timestamps)")
    console.print(
        f"gyro bias: {np.array2string(np.degrees(fit.bias), precision=2)} deg/s in the IMU's "
        f"axes ({np.array2string(np.degrees(bias_cam), precision=2)} in the camera's)"
    )
    spread = np.degrees(fit.spread_rad_s)
    if spread[1] < 0.2 * spread[0] or spread[2] < 0.05 * spread[0]:
        axes = "one axis" if spread[1] < 0.2 * spread[0] else "two axes"
        console.print(
            f"warning: the motion spans mainly {axes} "
            f"(spread {np.array2string(spread, precision=1)} deg/s): the rotation about the "
            "unexcited axes is not determined; record motion about all three axes."
        )
    typer.echo(f"--imu-to-camera {text}")
