"""``spikegyro predict`` (stream an event file or a live source through an estimator: the SNN,
or contrast maximization for real cameras, and write each estimate of ω), ``spikegyro baseline
cmax`` (contrast maximization on an event file: the offline engine of ``predict --method cmax
--offline``, or with ``--live`` the live one) and ``spikegyro calibrate-imu`` (the gyro's frame,
bias and clock offset).

``predict`` lives here rather than in :mod:`spikegyro.stream`: it chooses between the two
estimators, and contrast maximization sits above the stream runtime it runs in (see the
package layout in the documentation)."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import typer
from rich.console import Console

from spikegyro import options
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.files import (
    cmax_estimator_for_file,
    cmax_estimator_for_stream,
    estimate_whole_file,
    stream_camera_note,
)
from spikegyro.cmax.offline import offline_estimator_for_file
from spikegyro.cmax.windows import WindowPolicy
from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration
from spikegyro.events.imu import ImuFit, fit_imu_to_camera, rotation_text
from spikegyro.events.io import EVENT_FILE_HELP, read_gyro
from spikegyro.events.sources import URL_HELP, is_live, open_source
from spikegyro.pretrained import checkpoint_help
from spikegyro.stream.console import (
    EVENTS,
    PREDICTIONS_OUT,
    StreamInputs,
    print_lines,
    stream_inputs,
    stream_with_progress,
)
from spikegyro.stream.engine import load_engine
from spikegyro.stream.estimator import GyroEstimator
from spikegyro.stream.live import check_live_options, run_live
from spikegyro.stream.model import DEFAULT_CHECKPOINT
from spikegyro.stream.predict import (
    SNN_REAL_DATA_NOTE,
    SNNEstimator,
    is_simulated,
    spec_with,
    summary_lines,
)
from spikegyro.stream.writer import (
    STDOUT,
    check_prediction_path,
    read_predictions,
    write_predictions,
)

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
PREDICT_RATE_HZ = typer.Option(
    None,
    "--rate-hz",
    min=0.0,
    help="Estimates per second. cmax: default 100, 0 = one per chunk of events; snn: its "
    "1 ms bins, a divisor of 1000 keeps one bin in 1000/rate.",
)
PREDICT_WINDOW_MS = typer.Option(
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
PREDICT_CALIB = typer.Option(
    None,
    "--calib",
    help="Sensor calibration: 'fx fy cx cy k1 k2 p1 p2 k3' (the Event Camera Dataset's "
    "calib.txt; taken from an ECD folder by default); events are undistorted and "
    "reprojected onto the model's camera.",
)
PREDICT_GYRO = typer.Option(
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
    rate_hz: float = PREDICT_RATE_HZ,
    window_ms: float = PREDICT_WINDOW_MS,
    offline: bool = OFFLINE,
    checkpoint: Path = CHECKPOINT,
    calib: Path = PREDICT_CALIB,
    intrinsics: tuple[float, float, float, float] = options.INTRINSICS,
    gyro: Path = PREDICT_GYRO,
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
    network = _Network(checkpoint, (device, threads, segment_ms, context_ms, batch), clock, pixels)
    if live:  # the estimator first: the stream does not wait for it
        estimator = _live_estimator(method, events, inputs, rate_hz, window_ms, network)
        source = open_source(events)
        if method == "cmax":
            console.print(stream_camera_note(source.name, source.sensor, inputs.calibration))
        run_live(console, source, estimator, out, start, end, inputs.gyro_rotation, method)
        return
    events = Path(events)
    if method == "cmax":
        estimator, note = (
            offline_estimator_for_file(events, inputs.calibration, inputs.sensor, rate_hz)
            if offline
            else cmax_estimator_for_file(
                events, inputs.calibration, inputs.sensor, rate_hz, window_ms
            )
        )
        console.print(note)
    else:
        estimator = network.estimator(inputs.calibration, rate_hz, str(events))
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


@dataclass(frozen=True)
class _Network:
    """``predict``'s spiking network: ``--checkpoint`` (default the shipped one), how it runs
    (device, threads, segment_ms, context_ms, batch) and ``--clock`` / ``--pixels``."""

    checkpoint: Path | None
    engine_options: tuple
    clock: str | None
    pixels: str | None

    def estimator(
        self, calibration: Calibration | None, rate_hz: float | None, source: str
    ) -> SNNEstimator:
        engine, payload = load_engine(self.checkpoint or DEFAULT_CHECKPOINT, *self.engine_options)
        spec = spec_with(payload.get("input", {}), self.clock, self.pixels)
        return SNNEstimator(engine, spec, calibration, rate_hz, source)


def _live_estimator(
    method: str,
    source: str,
    inputs: StreamInputs,
    rate_hz: float | None,
    window_ms: float | None,
    network: _Network,
) -> GyroEstimator:
    """The estimator for a live source, ready before it connects (the sensor comes with the
    first batch)."""
    if method == "cmax":
        return cmax_estimator_for_stream(inputs.calibration, rate_hz, window_ms)
    return network.estimator(inputs.calibration, rate_hz, source)


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
