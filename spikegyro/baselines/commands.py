"""``spikegyro baseline cmax``: contrast maximization on an event file, output as ``predict``."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from spikegyro.baselines.cmax import CMaxConfig, camera_from_attrs, per_ms, predict_stream
from spikegyro.checks import sensor_option
from spikegyro.errors import InputError
from spikegyro.events.calib import resolve_calibration
from spikegyro.events.imu import IMU_TO_CAMERA_HELP, imu_rotation
from spikegyro.events.io import EVENT_FILE_HELP, read_gyro, read_recording
from spikegyro.stream.predict import WARMUP_STEPS, ErrorStats
from spikegyro.stream.writer import check_prediction_path, write_predictions

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
    window_events: int = typer.Option(
        CMaxConfig.window_events, "--window-events", min=100, help="Events per window."
    ),
    stride_events: int = typer.Option(
        CMaxConfig.stride_events, "--stride-events", min=1, help="Events between windows."
    ),
    window_ms: float = typer.Option(
        None, "--window-ms", min=0.1, help="Windows of this many ms instead of event counts."
    ),
    stride_ms: float = typer.Option(
        CMaxConfig.stride_ms, "--stride-ms", min=0.1, help="With --window-ms: ms between windows."
    ),
    whole: bool = typer.Option(
        False, "--whole", help="One estimate from all events between --start and --end."
    ),
    max_events: int = typer.Option(
        CMaxConfig.max_events, "--max-events", min=100, help="Subsample larger windows to this."
    ),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
) -> None:
    """Contrast maximization (Gallego & Scaramuzza 2017): ω every 1 ms, no training.

    By default each window holds --window-events events (every --stride-events) and its
    estimate stands for the window's middle; a stream shorter than a window is one window. The
    estimates are interpolated linearly onto 1 ms steps (held beyond the first and last).
    """
    # Without --calib/--intrinsics: the file's fx, fy, cx, cy attributes, else the simulator's
    # pinhole. The span is read into memory (CMax runs slower than real time anyway).
    if end is not None and end <= start:
        raise InputError(f"--end {end} s must be after --start {start} s.")
    check_prediction_path(out)
    console = Console(stderr=True)
    calibration, calib_file = resolve_calibration(events, calib, intrinsics)
    if calib_file is not None:
        console.print(f"using the calibration {calib_file}")
    rec = read_recording(events, sensor=sensor_option(width, height))
    if not len(rec.events):
        raise InputError(f"{events}: the file holds no events.")
    camera = calibration or camera_from_attrs(rec.attrs, *rec.events.sensor_size)
    t0 = int(rec.events.t[0]) // BIN_US * BIN_US + round(start * 1e6)
    t_end = int(rec.events.t[-1]) + 1 if end is None else t0 - round(start * 1e6) + round(end * 1e6)
    ev = rec.events.slice_time(t0, t_end)
    if not len(ev):
        raise InputError(f"{events}: no events between --start and --end.")
    config = replace(CMaxConfig(), max_events=max_events)
    if whole:
        config = replace(config, window_events=len(ev), stride_events=len(ev))
    elif window_ms is not None:
        config = replace(config, window_ms=window_ms, stride_ms=stride_ms)
    else:
        config = replace(config, window_events=window_events, stride_events=stride_events)
    steps = -(-(t_end - t0) // BIN_US)
    columns = [
        TextColumn("[bold]cmax"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("estimates"),
        TimeElapsedColumn(),
    ]
    wall = time.perf_counter()
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("cmax", total=None)
        t_us, omega = predict_stream(
            ev,
            camera,
            config,
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )
    wall = time.perf_counter() - wall
    times = t0 + BIN_US * (np.arange(steps, dtype=np.int64) + 1)
    rows = per_ms(t_us, omega, times)
    reference = None
    stats = ErrorStats()
    if gyro is not None:
        trace = read_gyro(
            gyro, imu_to_camera=imu_rotation(imu_to_camera) if imu_to_camera else None
        )
        reference = trace.interpolate(times)
        reference[(times < trace.t[0]) | (times > trace.t[-1])] = np.nan
        scored = times > t0 + WARMUP_STEPS * BIN_US
        stats.add(rows[scored], reference[scored])
    write_predictions(out, times, rows, reference)
    console.print(
        f"{len(t_us):,} estimates ({steps / 1000:.3f} s, {len(ev):,} events) -> {out}; "
        f"{wall:.1f} s wall, {len(t_us) / max(wall, 1e-9):.1f} estimates/s, "
        f"{steps / 1000 / max(wall, 1e-9):.2f}× real time"
    )
    summary = stats.summary()
    if summary:
        console.print(
            f"vs gyro (from {WARMUP_STEPS} ms on, {summary['samples']:,} samples): mean error "
            f"{summary['mean_error_deg_s']:.1f} deg/s, RMSE {summary['rmse_deg_s']:.1f} deg/s, "
            f"median relative error {summary['median_relative_error']:.3f}"
        )
