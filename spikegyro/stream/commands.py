"""``spikegyro predict``: stream an event file through an estimator (the SNN, or contrast
maximization for real cameras) and write each estimate of ω."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from spikegyro.checks import sensor_option
from spikegyro.errors import InputError
from spikegyro.events.calib import resolve_calibration
from spikegyro.events.imu import IMU_TO_CAMERA_HELP, gyro_frame
from spikegyro.events.io import EVENT_FILE_HELP
from spikegyro.stream.model import DEFAULT_CHECKPOINT, load_streaming_model
from spikegyro.stream.predict import (
    SNN_REAL_DATA_NOTE,
    WARMUP_STEPS,
    SNNEstimator,
    is_simulated,
    predict_stream,
    read_time_span,
    summary_lines,
)
from spikegyro.stream.writer import check_prediction_path


def predict(
    events: Path = typer.Argument(
        ...,
        help=EVENT_FILE_HELP,
    ),
    method: str = typer.Option(
        "snn",
        "--method",
        help="'snn': the paper's spiking network (default; not yet accurate on real cameras). "
        "'cmax': contrast maximization, causal windows adapted to the event rate and motion, "
        "with a confidence per estimate: use it for real cameras.",
    ),
    rate_hz: float = typer.Option(
        None,
        "--rate-hz",
        min=0.0,
        help="Estimates per second. cmax: default 100, 0 = one per chunk of events; snn: its "
        "1 ms bins, a divisor of 1000 keeps one bin in 1000/rate.",
    ),
    window_ms: float = typer.Option(
        None,
        "--window-ms",
        min=0.1,
        help="cmax: a fixed causal window of this many ms instead of the adaptive one.",
    ),
    checkpoint: Path = typer.Option(
        None,
        "--checkpoint",
        help="Trained SNN checkpoint (default: the shipped pretrained SNN-6, "
        "spikegyro/data/pretrained/snn6.pt).",
    ),
    calib: Path = typer.Option(
        None,
        "--calib",
        help="Sensor calibration: 'fx fy cx cy k1 k2 p1 p2 k3' (the Event Camera Dataset's "
        "calib.txt; taken from an ECD folder by default); events are undistorted and "
        "reprojected onto the model's camera.",
    ),
    intrinsics: tuple[float, float, float, float] = typer.Option(
        None, "--intrinsics", help="Sensor pinhole intrinsics fx fy cx cy (pixels), no distortion."
    ),
    gyro: Path = typer.Option(
        None,
        "--gyro",
        help="Reference angular velocity (gyro 't wx wy wz', IMU 't ax ay az gx gy gz', or a file "
        "with ground truth): adds it and the error to the output, prints metrics, draws a plot.",
    ),
    imu_to_camera: str = typer.Option(None, "--imu-to-camera", help=IMU_TO_CAMERA_HELP),
    start: float = typer.Option(0.0, "--start", help="Start, seconds after the first event."),
    end: float = typer.Option(None, "--end", help="End, seconds after the first event."),
    out: Path = typer.Option(Path("pred.csv"), "--out", "-o", help="Output .csv or .h5."),
    width: int = typer.Option(None, help="Sensor width, pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height, pixels (text files default to 180)."),
    threads: int = typer.Option(
        1,
        "--threads",
        min=1,
        max=2,
        help="CPU threads: 2 runs the network's layers as a two-stage pipeline on two cores.",
    ),
    device: str = typer.Option(
        "stream",
        "--device",
        help="'stream': the exact event-driven engine on the CPU, 1 ms at a time. A torch "
        "device ('cuda', 'cuda:1', 'cpu'): throughput instead; the recording is cut into "
        "segments, each run from rest after --context-ms of warm-up, batched through the "
        "network; approximate (median |Δω| ~1e-3 of |ω| on SNN-6).",
    ),
    segment_ms: int = typer.Option(
        400, "--segment-ms", min=1, help="Batched device: outputs per segment, ms."
    ),
    context_ms: int = typer.Option(
        100, "--context-ms", min=0, help="Batched device: warm-up before each segment, ms."
    ),
    batch: int = typer.Option(
        None, "--batch", min=1, help="Batched device: segments per pass (default: from memory)."
    ),
) -> None:
    """Estimate ω = (ω_x, ω_y, ω_z) in rad/s, streaming, with a real-time-factor bar.

    For real cameras use --method cmax (contrast maximization: 100 causal estimates per second,
    faster than real time on one core); the SNN (the default) is the paper's network and is
    not yet accurate on real recordings. Each output row is its own estimate, stamped at the
    time up to which it used events.
    """
    if method not in ("snn", "cmax"):
        raise InputError(f"--method {method}: choose 'snn' or 'cmax'.")
    check_prediction_path(out)
    console = Console(stderr=True)
    calibration, calib_file = resolve_calibration(events, calib, intrinsics)
    if calib_file is not None:
        console.print(f"using the calibration {calib_file}")
    sensor = sensor_option(width, height)
    frame = gyro_frame(gyro, imu_to_camera) if gyro is not None else None
    if frame is not None and frame.message:
        console.print(("warning: " if frame.warning else "") + frame.message)
    payload: dict = {}
    checkpoint = checkpoint or DEFAULT_CHECKPOINT
    if method == "cmax":
        # The CLI layer wires the estimators together; the stream package needs no baseline.
        from spikegyro.baselines.cmax_stream import cmax_estimator_for_file

        engine, note = cmax_estimator_for_file(events, calibration, sensor, rate_hz, window_ms)
        console.print(note)
    elif device == "stream":
        engine, payload = load_streaming_model(checkpoint, threads=threads)
    else:  # torch is imported only here: the stream needs none once the spec is cached
        from spikegyro.stream.batched import SegmentConfig, batched_predictor

        config = SegmentConfig(segment_ms, context_ms, batch)
        engine, payload = batched_predictor(checkpoint, device, config)
    if method == "snn":
        if window_ms is not None:
            raise InputError("--window-ms is for --method cmax; the SNN has no window.")
        engine = SNNEstimator(engine, payload.get("input", {}), calibration, rate_hz, str(events))
        if not is_simulated(events):
            console.print(SNN_REAL_DATA_NOTE)
    span = read_time_span(events)
    total_s = None
    if span is not None:
        total_s = max(0.0, (span[1] - span[0]) / 1e6 - start)
        total_s = total_s if end is None else min(total_s, end - start)
    columns = [
        TextColumn("[bold]predict"),
        BarColumn(),
        TextColumn("{task.completed:.1f}/{task.fields[total_text]} s of events"),
        TextColumn("[cyan]{task.fields[rtf]}× real time"),
        TimeElapsedColumn(),
    ]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(
            "predict", total=total_s, total_text=f"{total_s:.1f}" if total_s else "?", rtf="-"
        )

        def update(done_s: float, wall_s: float) -> None:
            rtf = f"{done_s / wall_s:.1f}" if wall_s > 0 else "-"
            progress.update(task, completed=done_s, rtf=rtf)

        result = predict_stream(
            events,
            engine,
            payload.get("input", {}),
            out,
            calibration=calibration,
            gyro_path=gyro,
            gyro_rotation=frame.rotation if frame is not None else None,
            sensor=sensor,
            start_s=start,
            end_s=end,
            on_progress=update,
        )
    lines = summary_lines(result, out)
    for line in lines[:2]:
        console.print(line)
    if method == "snn" and result.steps <= WARMUP_STEPS:
        console.print(
            f"warning: {result.steps} ms of output is within the network's {WARMUP_STEPS} ms "
            "warm-up, where it reads about zero; predict over a longer span to get estimates."
        )
    for line in lines[2:]:
        console.print(line)
