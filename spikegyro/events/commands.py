"""``spikegyro info`` (a summary of an event file) and ``spikegyro convert`` (between formats)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from spikegyro.events.convert import convert
from spikegyro.events.imu import imu_rotation
from spikegyro.events.io import detect_format, read_recording


def info(
    path: Path = typer.Argument(
        ...,
        help="Event file: .h5/.hdf5, .npz, events.txt or a folder, AEDAT 2/3.1/4, Prophesee "
        ".raw/.dat, a ROS bag.",
    ),
    width: int = typer.Option(None, help="Sensor width in pixels (text files default to 240)."),
    height: int = typer.Option(None, help="Sensor height in pixels (text files default to 180)."),
) -> None:
    """Print sensor size, event count, duration, rate, polarity balance and gyro statistics."""
    sensor = (width, height) if width and height else None
    rec = read_recording(path, sensor=sensor)
    ev = rec.events
    table = Table(title=f"{path} ({detect_format(path)})", show_header=False)
    table.add_row("sensor", f"{ev.width} x {ev.height} px")
    table.add_row("events", f"{len(ev):,}")
    duration_s = ev.duration_us / 1e6
    table.add_row("time span", f"{ev.t[0] / 1e6:.6f} .. {ev.t[-1] / 1e6:.6f} s" if len(ev) else "-")
    table.add_row("duration", f"{duration_s:.6f} s")
    if duration_s > 0:
        rate = len(ev) / duration_s
        table.add_row(
            "event rate", f"{rate / 1e6:.3f} Mev/s ({rate / (ev.width * ev.height):.1f} ev/px/s)"
        )
    if len(ev):
        table.add_row("ON fraction", f"{ev.p.mean():.3f}")
    if rec.gyro is not None and len(rec.gyro):
        w = np.degrees(rec.gyro.omega)
        norm = np.linalg.norm(w, axis=1)
        table.add_row("gyro samples", f"{len(rec.gyro):,}")
        table.add_row("|omega| mean / max", f"{norm.mean():.1f} / {norm.max():.1f} deg/s")
        for k, name in enumerate(("tilt x", "pan y", "roll z")):
            table.add_row(
                f"omega {name}", f"mean {w[:, k].mean():+.1f}, std {w[:, k].std():.1f} deg/s"
            )
    for key, value in sorted(rec.attrs.items()):
        table.add_row(f"attr {key}", str(value)[:80])
    Console().print(table)


def convert_command(
    src: Path = typer.Argument(..., help="Input: any readable event file (see spikegyro info)."),
    dst: Path = typer.Argument(
        ..., help="Output: .h5, .npz, .txt, a folder (events.txt + gyro.txt), .aedat4, .raw, .dat."
    ),
    width: int = typer.Option(None, help="Sensor width in pixels (when the input lacks it)."),
    height: int = typer.Option(None, help="Sensor height in pixels (when the input lacks it)."),
    imu_to_camera: str = typer.Option(
        None,
        "--imu-to-camera",
        help="Rotate the input's gyro into the camera frame: signed IMU axes per camera axis "
        "('-x,-y,z') or nine numbers (R row by row, ω_camera = R ω_imu).",
    ),
    chunk_events: int = typer.Option(1_000_000, min=1, help="Events per chunk (bounds memory)."),
) -> None:
    """Convert an event recording between formats, streaming it in bounded memory."""
    sensor = (width, height) if width and height else None
    rotation = imu_rotation(imu_to_camera) if imu_to_camera else None
    console = Console(stderr=True)
    columns = [
        TextColumn("[bold]convert"),
        SpinnerColumn(),
        TextColumn("{task.completed:,} events"),
    ]
    wall = time.perf_counter()
    with Progress(*columns, TimeElapsedColumn(), console=console, transient=True) as progress:
        task = progress.add_task("convert", total=None)
        n_events, n_gyro = convert(
            src,
            dst,
            sensor=sensor,
            imu_to_camera=rotation,
            chunk_events=chunk_events,
            progress=lambda n: progress.update(task, completed=n),
        )
    wall = time.perf_counter() - wall
    console.print(
        f"{src} ({detect_format(src)}) -> {dst}: {n_events:,} events, {n_gyro:,} gyro samples, "
        f"{wall:.1f} s ({n_events / max(wall, 1e-9) / 1e6:.2f} M events/s)"
    )
