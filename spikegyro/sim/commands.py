"""Commands ``simulate``, ``export-official`` and ``show``."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from spikegyro.checks import FIGURE_SUFFIXES, check_input, check_output_dir, check_output_file
from spikegyro.errors import InputError
from spikegyro.events.io import read_recording
from spikegyro.events.plot import plot_events_and_omega
from spikegyro.sim.camera import Camera
from spikegyro.sim.dataset import SimConfig, export_official, generate_dataset
from spikegyro.sim.sensor import SENSOR_PRESETS, EventSimConfig, sensor_preset
from spikegyro.sim.trajectory import TRAJECTORY_KINDS, TrajectoryConfig


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
    )


def _camera(width, height, fx, fy, cx, cy) -> Camera:
    """The default camera resized to the given sensor (aspect kept if one side is missing)."""
    ref = Camera()
    if width is None and height is None:
        base = ref
    else:
        width = width or round(height * ref.width / ref.height)
        height = height or round(width * ref.height / ref.width)
        base = Camera.scaled(width, height)
    return Camera(
        base.width,
        base.height,
        base.fx if fx is None else fx,
        base.fy if fy is None else fy,
        base.cx if cx is None else cx,
        base.cy if cy is None else cy,
    )


def _weights(text: str) -> tuple[float, ...]:
    """Comma-separated numbers, e.g. ``--scene-mix 0.4,0.25,0.2,0.15``."""
    try:
        return tuple(float(w) for w in text.split(","))
    except ValueError:
        raise InputError(
            f"--scene-mix {text}: give comma-separated numbers, e.g. 0.4,0.25,0.2,0.15 "
            "(sparse, office, photo, procedural)."
        ) from None


def _check_sim_options(
    contrast_mean: float,
    fx: float | None,
    fy: float | None,
    compression: str,
    panoramas: Path | None,
    sensor: str,
) -> None:
    """What Typer's ranges cannot say about ``simulate``'s options; before anything is written."""
    if not contrast_mean > 0:
        raise InputError(f"--contrast-mean {contrast_mean}: a contrast threshold must be > 0.")
    for option, value in (("--fx", fx), ("--fy", fy)):
        if value is not None and not value > 0:
            raise InputError(f"{option} {value}: a focal length must be positive (pixels).")
    if compression not in ("none", "lzf", "gzip"):
        raise InputError(f"--compression {compression}: use none, lzf or gzip.")
    if panoramas is not None and not panoramas.is_dir():
        raise InputError(f"{panoramas}: --panoramas must be a folder of images.")
    sensor_preset(sensor)  # rejects unknown names


# Options of `simulate` whose definitions span lines, kept here so the command reads as a list.
_PANORAMAS = typer.Option(
    None, "--panoramas", help="Folder of equirectangular images (default: bundled 12)."
)
_SCHEDULER = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://host:8786.")
_PROCEDURAL_FRACTION = typer.Option(
    0.3, min=0.0, max=1.0, help="Share of sequences on procedural panoramas."
)
_DETAIL = typer.Option(0.4, min=0.0, help="Log-intensity std of the texture added to photographs.")
_COMPRESSION = typer.Option(
    "none", help="HDF5 compression: none, lzf (~2x smaller) or gzip (~3.5x, slower)."
)
_SENSOR = typer.Option(
    "ideal",
    "--sensor",
    help=f"Sensor preset: {', '.join(SENSOR_PRESETS)}. 'ideal' is the paper's simulator "
    "(the options below); 'davis240c' draws thresholds, noise, hot pixels, bandwidth, lens "
    "and the scene mix per sequence (docs/simulator.md) and ignores the threshold, "
    "noise, --procedural-fraction and --detail options.",
)
_SCENE_MIX = typer.Option(
    None,
    "--scene-mix",
    help="With a sensor preset: weights of the scene kinds sparse,office,photo,procedural "
    "(e.g. 0.4,0.25,0.2,0.15) instead of the preset's.",
)
_SLOW_SHARE = typer.Option(
    0.0,
    "--slow-share",
    min=0.0,
    max=1.0,
    help="Share of sequences moving like a handheld camera or robot (slow, smooth).",
)
_SLOW_SPEED = typer.Option(
    (5.0, 100.0), "--slow-speed", help="Their speed range MIN MAX, deg/s (log-uniform)."
)
_OMEGA_SCALE = typer.Option(
    TrajectoryConfig.omega_scale_deg,
    "--omega-scale",
    min=0.0,
    help="The other sequences' per-axis speed scale, deg/s (the paper's motion: 107).",
)
_ACCEL_STD = typer.Option(
    TrajectoryConfig.accel_std_deg,
    "--accel-std",
    min=0.0,
    help="Their angular acceleration per axis, deg/s² (std).",
)

_TRAJECTORY = typer.Option(
    "random",
    "--trajectory",
    help="The motion: 'random' (the paper's random rotations, shaped by --slow-share, "
    "--omega-scale and --accel-std) or "
    "'flip' (a quadrotor's flip: a roll of --flip-deg degrees within --flip-ms milliseconds, "
    "centred in each sequence, over a small random tilt and pan; docs/simulator.md).",
)
_FLIP_DEG = typer.Option(360.0, "--flip-deg", help="The flip's roll angle, degrees.")
_FLIP_MS = typer.Option(
    600.0,
    "--flip-ms",
    help="How long the flip lasts, ms. Its roll rate peaks at twice the mean rate (1,200 deg/s "
    "for 360 degrees in 600 ms). Give a --duration-ms at least this long.",
)
_FLIP_DRIFT = typer.Option(
    10.0, "--flip-drift", help="The spread of the tilt and pan rates under the flip, deg/s."
)


def simulate_dataset(
    out: Path = typer.Option(..., "--out", help="Dataset folder (created; resumed if present)."),
    sequences: int = typer.Option(..., "--sequences", min=1, help="Sequences over all splits."),
    duration_ms: int = typer.Option(500, "--duration-ms", min=100, help="Sequence length, ms."),
    seed: int = typer.Option(0, "--seed", help="Dataset seed; same seed, same files."),
    panoramas: Path = _PANORAMAS,
    workers: int = typer.Option(1, "--workers", min=1, help="Local worker processes."),
    scheduler: str = _SCHEDULER,
    procedural_fraction: float = _PROCEDURAL_FRACTION,
    detail: float = _DETAIL,
    compression: str = _COMPRESSION,
    sensor: str = _SENSOR,
    scene_mix: str = _SCENE_MIX,
    slow_share: float = _SLOW_SHARE,
    slow_speed: tuple[float, float] = _SLOW_SPEED,
    omega_scale: float = _OMEGA_SCALE,
    accel_std: float = _ACCEL_STD,
    trajectory: str = _TRAJECTORY,
    flip_deg: float = _FLIP_DEG,
    flip_ms: float = _FLIP_MS,
    flip_drift: float = _FLIP_DRIFT,
    contrast_mean: float = typer.Option(0.45, help="Mean contrast threshold (log units, > 0)."),
    contrast_std: float = typer.Option(0.05, min=0.0, help="Per-sequence threshold spread."),
    mismatch_std: float = typer.Option(0.03, min=0.0, help="Per-pixel threshold std."),
    noise_std: float = typer.Option(0.01, min=0.0, help="Per-crossing threshold std."),
    refractory_us: int = typer.Option(0, min=0, help="Refractory period, us (0: off)."),
    shot_noise_hz: float = typer.Option(0.0, min=0.0, help="Shot-noise events per pixel per s."),
    leak_hz: float = typer.Option(0.0, min=0.0, help="Leak (ON) events per pixel per s."),
    width: int = typer.Option(None, min=1, help="Sensor width, px (default 240)."),
    height: int = typer.Option(None, min=1, help="Sensor height, px (default 180)."),
    fx: float = typer.Option(None, help="Focal length x, px (default 200, scaled with width)."),
    fy: float = typer.Option(None, help="Focal length y, px."),
    cx: float = typer.Option(None, help="Principal point x, px."),
    cy: float = typer.Option(None, help="Principal point y, px."),
) -> None:
    """Simulate a dataset of rotating-event-camera sequences with exact angular velocity."""
    check_output_dir(out)
    _check_sim_options(contrast_mean, fx, fy, compression, panoramas, sensor)
    config = SimConfig(
        duration_ms=duration_ms,
        camera=_camera(width, height, fx, fy, cx, cy),
        trajectory=_trajectory(
            slow_share,
            slow_speed,
            omega_scale,
            accel_std,
            (trajectory, flip_deg, flip_ms, flip_drift),
            duration_ms,
        ),
        contrast_mean=contrast_mean,
        contrast_std=contrast_std,
        events=EventSimConfig(
            mismatch_std=mismatch_std,
            noise_std=noise_std,
            refractory_us=refractory_us,
            shot_noise_hz=shot_noise_hz,
            leak_hz=leak_hz,
        ),
        panoramas=None if panoramas is None else str(panoramas.resolve()),
        procedural_fraction=procedural_fraction,
        detail_strength=detail,
        sensor=sensor,
        scene_mix=None if scene_mix is None else _weights(scene_mix),
    )
    simulate_with_progress(
        out,
        sequences,
        seed,
        config,
        workers=workers,
        scheduler=scheduler,
        compression=None if compression == "none" else compression,
    )


def _trajectory(
    slow_share: float,
    slow_speed: tuple[float, float],
    omega_scale: float,
    accel_std: float,
    flip: tuple[str, float, float, float],
    duration_ms: int,
) -> TrajectoryConfig:
    """The motion's settings; ``flip``: (--trajectory, --flip-deg, --flip-ms, --flip-drift)."""
    kind, flip_deg, flip_ms, flip_drift = flip
    config = TrajectoryConfig(
        omega_scale_deg=omega_scale,
        accel_std_deg=accel_std,
        slow_share=slow_share,
        slow_min_deg=slow_speed[0],
        slow_max_deg=slow_speed[1],
        kind=kind,
        flip_deg=flip_deg,
        flip_ms=flip_ms,
        flip_drift_deg=flip_drift,
    )
    if kind not in TRAJECTORY_KINDS:
        raise InputError(f"--trajectory {kind}: use {' or '.join(TRAJECTORY_KINDS)}.")
    try:
        config.validate()
    except ValueError as exc:
        option = "--flip-deg/--flip-ms/--flip-drift" if "flip" in str(exc) else "--slow-speed"
        raise InputError(f"{option}: {exc}.") from None
    if kind == "flip" and flip_ms > duration_ms:
        raise InputError(
            f"--flip-ms {flip_ms:g}: the flip must fit in the sequence; give --duration-ms "
            f"{math.ceil(flip_ms)} or more (now {duration_ms})."
        )
    return config


def simulate_with_progress(
    out: Path,
    sequences: int,
    seed: int,
    config: SimConfig,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    compression: str | None = None,
    console: Console | None = None,
) -> dict:
    """:func:`generate_dataset` with a progress bar (events/s, ETA) and a one-line summary."""
    console = console or Console(stderr=True)
    start = time.perf_counter()
    events = 0
    with _progress() as progress:
        task = progress.add_task("simulating", total=sequences, rate="")

        def update(done: int, total: int, n_events: int) -> None:
            nonlocal events
            events += n_events
            rate = events / max(time.perf_counter() - start, 1e-9)
            progress.update(task, completed=done, rate=f"{rate / 1e6:.2f} Mev/s")

        meta = generate_dataset(
            out, sequences, seed, config, workers, scheduler, update, compression=compression
        )
    elapsed = time.perf_counter() - start
    stats = meta.get("statistics", {})
    per_window = stats.get("events_per_100ms", {})
    rate = stats.get("events_per_s_millions", {})
    console.print(
        f"{out}: {meta['sequences']} sequences, {stats.get('events_total', 0):,} events; "
        f"events per 100 ms median {per_window.get('p50', 0):,.0f}, "
        f"5th percentile {per_window.get('p5', 0):,.0f} "
        f"({rate.get('p5', 0):.2f}-{rate.get('p95', 0):.2f} M events/s, 5-95 %); "
        f"mean |omega| {stats.get('mean_omega_norm_deg_s', {}).get('mean', 0):.0f} deg/s; "
        f"{elapsed:.1f} s"
    )
    return meta


def export_official_command(
    src: Path = typer.Argument(..., help="Dataset folder made by 'spikegyro simulate'."),
    out: Path = typer.Argument(..., help="Output folder of 100 ms sample files."),
    window_ms: int = typer.Option(100, "--window-ms", min=1, help="Sample length, ms."),
) -> None:
    """Cut every sequence into window-long sample files in exactly the official layout."""
    check_input(src, "SRC", folder=True)
    check_output_dir(out, "OUT")
    total = sum(1 for _ in src.glob("*/seq_*.h5"))
    if not total:
        raise InputError(f"{src}: no sequence files (DIR/{{train,val,test}}/seq_*.h5); give a "
                         "folder made by 'spikegyro simulate'.")  # fmt: skip
    with _progress() as progress:
        task = progress.add_task("exporting", total=total, rate="")
        written = export_official(src, out, window_ms, lambda: progress.advance(task))
    Console(stderr=True).print(f"{out}: {written} samples of {window_ms} ms")


def show(
    path: Path = typer.Argument(..., help="Event file with ground truth (.h5, .npz, ...)."),
    out: Path = typer.Option(..., "--out", help="Figure path (.png, .pdf, .svg)."),
    start_ms: float = typer.Option(0.0, "--start-ms", help="Window start, ms from t = 0."),
    window_ms: float = typer.Option(100.0, "--window-ms", min=0.001, help="Window length, ms."),
    max_events: int = typer.Option(40_000, min=1, help="Draw at most this many events."),
) -> None:
    """Plot a window's events in space-time (ON red, OFF blue) above omega(t) on 3 axes."""
    check_output_file(out, "--out", FIGURE_SUFFIXES)
    rec = read_recording(path)
    t0, t1 = round(start_ms * 1000), round((start_ms + window_ms) * 1000)
    events = rec.events.slice_time(t0, t1)
    if rec.gyro is not None:
        gyro = rec.gyro.slice_time(t0, t1 + 1)
        omega_t, omega = gyro.t / 1e6, gyro.omega
    else:
        omega_t, omega = None, None
    if len(events) == 0 and omega is None:
        raise InputError(f"{path}: nothing in [{start_ms}, {start_ms + window_ms}) ms to show.")
    title = f"{path.name}  [{start_ms:g}, {start_ms + window_ms:g}) ms"
    plot_events_and_omega(
        events, omega_t, omega, out=out, title=title, max_events=max_events, t0_s=t0 / 1e6
    )
    Console(stderr=True).print(f"{out}: {len(events):,} events, {np.size(omega_t)} omega samples")
