"""``spikegyro predict``: stream an event file through an estimator (the SNN, or contrast
maximization for real cameras) and write each estimate of ω."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from spikegyro import options
from spikegyro.errors import InputError
from spikegyro.events.io import EVENT_FILE_HELP
from spikegyro.events.sources import URL_HELP, is_live, open_source
from spikegyro.pretrained import checkpoint_help
from spikegyro.stream.console import (
    PREDICTIONS_OUT,
    StreamInputs,
    print_lines,
    stream_inputs,
    stream_with_progress,
)
from spikegyro.stream.estimator import GyroEstimator
from spikegyro.stream.live import check_live_options, run_live
from spikegyro.stream.model import DEFAULT_CHECKPOINT, load_engine
from spikegyro.stream.predict import (
    SNN_REAL_DATA_NOTE,
    SNNEstimator,
    is_simulated,
    spec_with,
    summary_lines,
)
from spikegyro.stream.writer import STDOUT, check_prediction_path

SOURCE = typer.Argument(
    ..., help=f"{EVENT_FILE_HELP} Or a live source: {URL_HELP} (see docs/live.md)."
)
METHOD = typer.Option(
    None,
    "--method",
    help="'snn': the paper's spiking network (default for files; not yet accurate on real "
    "cameras). 'cmax': contrast maximization, causal windows adapted to the event rate and "
    "motion, with a confidence per estimate: use it for real cameras (default for live "
    "sources).",
)
RATE_HZ = typer.Option(
    None,
    "--rate-hz",
    min=0.0,
    help="Estimates per second. cmax: default 100, 0 = one per chunk of events; snn: its "
    "1 ms bins, a divisor of 1000 keeps one bin in 1000/rate.",
)
WINDOW_MS = typer.Option(
    None,
    "--window-ms",
    min=0.1,
    help="cmax: a fixed causal window of this many ms instead of the adaptive one.",
)
OFFLINE = typer.Option(
    False,
    "--offline",
    help="cmax on a file: each estimate from the events on both sides of its time, with the "
    "events and iterations accuracy needs (post-processing; not causal).",
)
CHECKPOINT = typer.Option(
    None,
    "--checkpoint",
    help=checkpoint_help("Trained SNN checkpoint"),
)
CALIB = typer.Option(
    None,
    "--calib",
    help="Sensor calibration: 'fx fy cx cy k1 k2 p1 p2 k3' (the Event Camera Dataset's "
    "calib.txt; taken from an ECD folder by default); events are undistorted and "
    "reprojected onto the model's camera.",
)
GYRO = typer.Option(
    None,
    "--gyro",
    help="Reference angular velocity (gyro 't wx wy wz', IMU 't ax ay az gx gy gz', or a file "
    "with ground truth): adds it and the error to the output, prints metrics, draws a plot.",
)
THREADS = typer.Option(
    1,
    "--threads",
    min=1,
    max=2,
    help="CPU threads: 2 runs the network's layers as a two-stage pipeline on two cores.",
)
DEVICE = typer.Option(
    "stream",
    "--device",
    help="'stream': the exact event-driven engine on the CPU, 1 ms at a time. A torch "
    "device ('cuda', 'cuda:1', 'cpu'): throughput instead; the recording is cut into "
    "segments, each run from rest after --context-ms of warm-up, batched through the "
    "network; approximate (median |Δω| ~1e-3 of |ω| on SNN-6).",
)
SEGMENT_MS = typer.Option(
    400, "--segment-ms", min=1, help="Batched device: outputs per segment, ms."
)
CONTEXT_MS = typer.Option(
    100, "--context-ms", min=0, help="Batched device: warm-up before each segment, ms."
)
BATCH = typer.Option(
    None, "--batch", min=1, help="Batched device: segments per pass (default: from memory)."
)


def predict(
    events: str = SOURCE,
    method: str | None = METHOD,
    rate_hz: float = RATE_HZ,
    window_ms: float = WINDOW_MS,
    offline: bool = OFFLINE,
    checkpoint: Path = CHECKPOINT,
    calib: Path = CALIB,
    intrinsics: tuple[float, float, float, float] = options.INTRINSICS,
    gyro: Path = GYRO,
    imu_to_camera: str = options.IMU_TO_CAMERA,
    start: float = options.START,
    end: float = options.END,
    out: Path = PREDICTIONS_OUT,
    width: int = options.WIDTH,
    height: int = options.HEIGHT,
    threads: int = THREADS,
    device: str = DEVICE,
    segment_ms: int = SEGMENT_MS,
    context_ms: int = CONTEXT_MS,
    batch: int = BATCH,
    clock: str = options.CLOCK,
    pixels: str = options.PIXELS,
) -> None:
    """Estimate ω = (ω_x, ω_y, ω_z) in rad/s, streaming, with a real-time-factor bar.

    For real cameras use --method cmax (contrast maximization: 100 causal estimates per second,
    faster than real time on one core); the SNN (the default for files) is the paper's network
    and is not yet accurate on real recordings. Each output row is its own estimate, stamped at
    the time up to which it used events. A live source (dv://HOST:PORT, camera://) runs until
    the stream ends, --end or Ctrl-C, writing each estimate as it completes (--out - for CSV
    on standard output).
    """
    live = is_live(events)
    method = _check_method(method, window_ms, live, offline)
    check_prediction_path(out)
    if live:
        check_live_options(events, gyro, width, height)
    inputs = stream_inputs(
        events, calib, intrinsics, gyro, imu_to_camera, width, height, start, end
    )
    console = Console(stderr=True)
    print_lines(console, inputs.notes)
    engine_options = (device, threads, segment_ms, context_ms, batch)
    network = (clock, pixels)
    if live:  # the estimator first: the stream does not wait for it
        estimator = _live_estimator(
            method, events, inputs, rate_hz, window_ms, checkpoint, engine_options, network
        )
        source = open_source(events)
        if method == "cmax":
            from spikegyro.cmax.files import stream_camera_note

            console.print(stream_camera_note(source.name, source.sensor, inputs.calibration))
        run_live(console, source, estimator, out, start, end, inputs.gyro_rotation, method)
        return
    events = Path(events)
    if method == "cmax":
        # The CLI layer wires the estimators together; the stream package needs no baseline.
        from spikegyro.cmax.files import cmax_estimator_for_file
        from spikegyro.cmax.offline import offline_estimator_for_file

        estimator, note = (
            offline_estimator_for_file(events, inputs.calibration, inputs.sensor, rate_hz)
            if offline
            else cmax_estimator_for_file(
                events, inputs.calibration, inputs.sensor, rate_hz, window_ms
            )
        )
        console.print(note)
    else:
        estimator = _snn_estimator(
            checkpoint, engine_options, inputs, rate_hz, str(events), network
        )
    result = stream_with_progress(
        console, "predict", events, estimator, out, sensor=inputs.sensor, start_s=start,
        end_s=end, gyro_path=gyro, gyro_rotation=inputs.gyro_rotation, plot=str(out) != STDOUT,
    )  # fmt: skip
    snn = method == "snn"
    print_lines(console, summary_lines(result, out, warm_up=snn))
    if snn and not is_simulated(events):  # after the run: an unreadable file is one error line
        console.print(SNN_REAL_DATA_NOTE)


def _check_method(
    method: str | None, window_ms: float | None, live: bool, offline: bool = False
) -> str:
    """``--method`` is known (default: cmax for a live source, snn for a file), and
    ``--window-ms`` goes with cmax only, ``--offline`` with cmax on a file without
    ``--window-ms``; returns the method."""
    method = method or ("cmax" if live else "snn")
    if method not in ("snn", "cmax"):
        raise InputError(f"--method {method}: choose 'snn' or 'cmax'.")
    if method == "snn" and window_ms is not None:
        raise InputError("--window-ms is for --method cmax; the SNN has no window.")
    if offline and (method != "cmax" or live or window_ms is not None):
        raise InputError(
            "--offline is for --method cmax on a file, and sizes its own windows (no --window-ms)."
        )
    return method


def _live_estimator(
    method: str,
    source: str,
    inputs: StreamInputs,
    rate_hz: float | None,
    window_ms: float | None,
    checkpoint: Path | None,
    engine_options: tuple,
    network: tuple[str | None, str | None],
) -> GyroEstimator:
    """The estimator for a live source, ready before it connects (the sensor comes with the
    first batch)."""
    if method == "cmax":
        from spikegyro.cmax.files import cmax_estimator_for_stream

        return cmax_estimator_for_stream(inputs.calibration, rate_hz, window_ms)
    return _snn_estimator(checkpoint, engine_options, inputs, rate_hz, source, network)


def _snn_estimator(
    checkpoint: Path | None,
    engine_options: tuple,
    inputs: StreamInputs,
    rate_hz: float | None,
    source: str,
    network: tuple[str | None, str | None],
) -> SNNEstimator:
    """The network (``--checkpoint``, default the shipped one) with its clock and pixels, or
    those of ``network`` (``--clock``, ``--pixels``)."""
    engine, payload = load_engine(checkpoint or DEFAULT_CHECKPOINT, *engine_options)
    spec = spec_with(payload.get("input", {}), *network)
    return SNNEstimator(engine, spec, inputs.calibration, rate_hz, source)
