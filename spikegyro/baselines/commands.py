"""``spikegyro baseline cmax`` (contrast maximization on an event file, the engine of ``predict
--method cmax``) and ``spikegyro calibrate-imu`` (the gyro's frame, bias and clock offset)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from spikegyro.baselines.cmax import CMaxConfig, WindowPolicy, estimate_window
from spikegyro.baselines.cmax_stream import camera_for_file, cmax_estimator_for_file
from spikegyro.checks import sensor_option
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration, resolve_calibration
from spikegyro.events.imu import (
    IMU_TO_CAMERA_HELP,
    ImuFit,
    fit_imu_to_camera,
    gyro_frame,
    rotation_text,
)
from spikegyro.events.io import EVENT_FILE_HELP, read_gyro, read_recording
from spikegyro.stream.predict import predict_stream, summary_lines
from spikegyro.stream.writer import check_prediction_path, read_predictions, write_predictions

BIN_US = 1000

app = typer.Typer(
    help="Non-learned baselines that read event files like `spikegyro predict`.",
    no_args_is_help=True,
)


@app.command("cmax")
def cmax_command(
    events: Path = typer.Argument(
        ...,
        help=EVENT_FILE_HELP,
    ),
    calib: Path = typer.Option(
        None,
        "--calib",
        help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt; taken from an ECD "
        "folder by default); events are undistorted to rays with it.",
    ),
    intrinsics: tuple[float, float, float, float] = typer.Option(
        None, "--intrinsics", help="Sensor pinhole intrinsics fx fy cx cy (pixels), no distortion."
    ),
    gyro: Path = typer.Option(
        None,
        "--gyro",
        help="Reference angular velocity (gyro/IMU text or a file with ground truth): adds it "
        "and the error to the output and prints metrics.",
    ),
    imu_to_camera: str = typer.Option(None, "--imu-to-camera", help=IMU_TO_CAMERA_HELP),
    start: float = typer.Option(0.0, "--start", help="Start, seconds after the first event."),
    end: float = typer.Option(None, "--end", help="End, seconds after the first event."),
    out: Path = typer.Option(Path("pred.csv"), "--out", "-o", help="Output .csv or .h5."),
    rate_hz: float = typer.Option(
        CMaxConfig.rate_hz,
        "--rate-hz",
        min=0.0,
        help="Estimates per second of events; 0: one per chunk of events read.",
    ),
    window_ms: float = typer.Option(
        None, "--window-ms", min=0.1, help="A fixed causal window of this many ms (else adaptive)."
    ),
    window_events: int = typer.Option(
        None, "--window-events", min=100, help="A fixed causal window of the last N events."
    ),
    whole: bool = typer.Option(
        False, "--whole", help="One estimate from all events between --start and --end."
    ),
    max_events: int = typer.Option(
        CMaxConfig.track_events,
        "--max-events",
        min=100,
        help="Events an estimate uses at most (larger windows are thinned evenly).",
    ),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
) -> None:
    """Contrast maximization (Gallego & Scaramuzza 2017), no training: the engine of
    `spikegyro predict --method cmax`, with its window settings exposed.

    Each estimate, at --rate-hz, uses only the events before it, in a window that adapts to the
    event rate and the motion (or is fixed by --window-ms or --window-events); each row is its
    own estimate with its confidence. --whole gives one estimate from all events instead.
    """
    if end is not None and end <= start:
        raise InputError(f"--end {end} s must be after --start {start} s.")
    if window_ms is not None and window_events is not None:
        raise InputError("--window-ms and --window-events: give one of them, not both.")
    check_prediction_path(out)
    console = Console(stderr=True)
    calibration, calib_file = resolve_calibration(events, calib, intrinsics)
    if calib_file is not None:
        console.print(f"using the calibration {calib_file}")
    sensor = sensor_option(width, height)
    frame = gyro_frame(gyro, imu_to_camera) if gyro is not None else None
    if frame is not None and frame.message:
        console.print(("warning: " if frame.warning else "") + frame.message)
    window = WindowPolicy(fixed_ms=window_ms or 0.0, fixed_events=window_events or 0)
    config = CMaxConfig(rate_hz=rate_hz, window=window, track_events=max_events)
    if whole:
        _whole(events, calibration, sensor, start, end, out, console)
        return
    estimator, note = cmax_estimator_for_file(events, calibration, sensor, config=config)
    console.print(note)
    columns = [
        TextColumn("[bold]cmax"),
        BarColumn(),
        TextColumn("{task.completed:.2f} s of events"),
        TimeElapsedColumn(),
    ]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("cmax", total=None)
        result = predict_stream(
            events,
            estimator,
            None,
            out,
            gyro_path=gyro,
            gyro_rotation=frame.rotation if frame is not None else None,
            sensor=sensor,
            start_s=start,
            end_s=end,
            on_progress=lambda done_s, _wall: progress.update(task, completed=done_s),
        )
    for line in summary_lines(result, out):
        console.print(line)


def _whole(
    events: Path,
    calibration: Calibration | None,
    sensor: tuple[int, int] | None,
    start: float,
    end: float | None,
    out: Path,
    console: Console,
) -> None:
    """One estimate from all events of the span (read into memory), stamped at its end."""
    rec = read_recording(events, sensor=sensor)
    if not len(rec.events):
        raise InputError(f"{events}: the file holds no events.")
    camera, note = camera_for_file(events, calibration, sensor)
    console.print(note)
    t0 = int(rec.events.t[0]) // BIN_US * BIN_US
    t_end = int(rec.events.t[-1]) + 1 if end is None else t0 + round(end * 1e6)
    ev = rec.events.slice_time(t0 + round(start * 1e6), t_end)
    if not len(ev):
        raise InputError(f"{events}: no events between --start and --end.")
    config = CMaxConfig(max_events=max(len(ev), 1))
    t_ref = int(ev.t[-1])
    omega = estimate_window(ev, camera, config, t_ref_us=t_ref)
    write_predictions(out, np.array([t_ref]), omega[None])
    console.print(
        f"one estimate from {len(ev):,} events ({ev.duration_us / 1000:.1f} ms), ω = "
        f"{np.array2string(np.degrees(omega), precision=1)} deg/s (tilt, pan, roll) -> {out}"
    )


def calibrate_imu(
    events: Path = typer.Argument(..., help=EVENT_FILE_HELP),
    gyro: Path = typer.Option(
        None,
        "--gyro",
        help="The raw gyro, in its IMU's axes (gyro/IMU text, or a camera file with an IMU); "
        "default: the event file's own IMU.",
    ),
    calib: Path = typer.Option(
        None, "--calib", help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt)."
    ),
    intrinsics: tuple[float, float, float, float] = typer.Option(
        None, "--intrinsics", help="Sensor pinhole intrinsics fx fy cx cy (pixels), no distortion."
    ),
    max_offset_ms: float = typer.Option(
        50.0, "--max-offset-ms", min=0.0, help="Clock offsets tried: within ± this many ms."
    ),
    start: float = typer.Option(0.0, "--start", help="Start, seconds after the first event."),
    end: float = typer.Option(None, "--end", help="End, seconds after the first event."),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
) -> None:
    """The gyro's IMU-to-camera rotation, bias and clock offset, from a recording with events
    and gyro: contrast maximization's camera-frame ω, then a least-squares rotation plus bias
    at the best clock offset. Prints the --imu-to-camera value to use.
    """
    console = Console(stderr=True)
    calibration, _ = resolve_calibration(events, calib, intrinsics)
    sensor = sensor_option(width, height)
    trace = read_gyro(gyro if gyro is not None else events)
    estimator, note = cmax_estimator_for_file(events, calibration, sensor)
    console.print(note)
    with tempfile.TemporaryDirectory() as tmp, Progress(
        TextColumn("[bold]cmax"), BarColumn(), TextColumn("{task.completed:.2f} s of events"),
        TimeElapsedColumn(), console=console, transient=True,
    ) as progress:  # fmt: skip
        task = progress.add_task("cmax", total=None)
        out = Path(tmp) / "cmax.h5"
        result = predict_stream(
            events, estimator, None, out, sensor=sensor, start_s=start, end_s=end,
            on_progress=lambda done_s, _wall: progress.update(task, completed=done_s),
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
