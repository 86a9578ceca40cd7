"""``spikegyro baseline cmax``: contrast maximization on an event file, output as ``predict``."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from spikegyro.baselines.cmax import CMaxConfig, camera_from_attrs, hold_per_ms, predict_stream
from spikegyro.errors import InputError
from spikegyro.events.calib import resolve_calibration
from spikegyro.events.io import read_gyro, read_recording
from spikegyro.stream.predict import WARMUP_STEPS, ErrorStats, event_mapper, model_camera
from spikegyro.stream.writer import check_prediction_path, write_predictions

BIN_US = 1000

app = typer.Typer(
    help="Non-learned baselines that read event files like `spikegyro predict`.",
    no_args_is_help=True,
)


@app.command("cmax")
def cmax_command(
    events: Path = typer.Argument(
        ..., help="Event file: .h5/.hdf5, .npz, events.txt (t x y p) or an ECD folder."
    ),
    calib: Path = typer.Option(
        None,
        "--calib",
        help="Sensor calibration 'fx fy cx cy k1 k2 p1 p2 k3' (ECD calib.txt; taken from an ECD "
        "folder by default); events are undistorted onto the same pinhole.",
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
    start: float = typer.Option(0.0, "--start", help="Start, seconds after the first event."),
    end: float = typer.Option(None, "--end", help="End, seconds after the first event."),
    out: Path = typer.Option(Path("pred.csv"), "--out", "-o", help="Output .csv or .h5."),
    window_ms: float = typer.Option(
        CMaxConfig.window_ms, "--window-ms", min=1.0, help="Events per estimate, milliseconds."
    ),
    stride_ms: int = typer.Option(
        CMaxConfig.stride_ms, "--stride-ms", min=1, help="One estimate every this many ms."
    ),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
) -> None:
    """Contrast maximization (Gallego & Scaramuzza 2017): ω every 1 ms, no training.

    Each estimate uses the events of the preceding --window-ms and is held until the next one.
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
    rec = read_recording(events, sensor=(width, height) if width and height else None)
    if not len(rec.events):
        raise InputError(f"{events}: the file holds no events.")
    sensor = rec.events.sensor_size
    pinhole = calibration or camera_from_attrs(rec.attrs, *sensor)
    # The stream engineer's mapping: undistort onto a pinhole with the sensor's own intrinsics.
    spec = {"sensor": list(sensor), "intrinsics": [pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy]}
    camera = model_camera(spec)
    t0 = int(rec.events.t[0]) // BIN_US * BIN_US + round(start * 1e6)
    t_end = int(rec.events.t[-1]) + 1 if end is None else t0 - round(start * 1e6) + round(end * 1e6)
    ev = event_mapper(sensor, spec, calibration, str(events))(rec.events.slice_time(t0, t_end))
    if not len(ev):
        raise InputError(f"{events}: no events between --start and --end.")
    config = replace(CMaxConfig(), window_ms=window_ms, stride_ms=stride_ms)
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
            t_first_us=t0 + config.stride_ms * BIN_US,
            t_end_us=t0 + steps * BIN_US,
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )
    wall = time.perf_counter() - wall
    times = t0 + BIN_US * (np.arange(steps, dtype=np.int64) + 1)
    per_ms = hold_per_ms(t_us, omega, t0, steps)
    reference = None
    stats = ErrorStats()
    if gyro is not None:
        trace = read_gyro(gyro)
        reference = trace.interpolate(times)
        reference[(times < trace.t[0]) | (times > trace.t[-1])] = np.nan
        scored = times > t0 + WARMUP_STEPS * BIN_US
        stats.add(per_ms[scored], reference[scored])
    write_predictions(out, times, per_ms, reference)
    console.print(
        f"{len(t_us):,} estimates ({steps / 1000:.3f} s, {len(ev):,} events) -> {out}; "
        f"{wall:.1f} s wall, {len(t_us) / max(wall, 1e-9):.1f} windows/s, "
        f"{steps / 1000 / max(wall, 1e-9):.2f}× real time"
    )
    summary = stats.summary()
    if summary:
        console.print(
            f"vs gyro (from {WARMUP_STEPS} ms on, {summary['samples']:,} samples): mean error "
            f"{summary['mean_error_deg_s']:.1f} deg/s, RMSE {summary['rmse_deg_s']:.1f} deg/s, "
            f"median relative error {summary['median_relative_error']:.3f}"
        )
