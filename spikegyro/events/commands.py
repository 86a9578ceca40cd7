"""``spikegyro info`` (a summary of an event file), ``spikegyro convert`` (between formats) and
``spikegyro compare-stats`` (real recordings' event statistics against a simulated dataset's, see
:mod:`spikegyro.events.stats`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from spikegyro import options
from spikegyro.checks import check_output_dir, check_output_file, sensor_option
from spikegyro.errors import InputError
from spikegyro.events import stats
from spikegyro.events.convert import convert
from spikegyro.events.imu import imu_rotation
from spikegyro.events.io import atomic_dir, detect_format, read_recording, recording_name


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
    sensor = sensor_option(width, height)
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
    imu_to_camera: str = options.IMU_TO_CAMERA,
    chunk_events: int = typer.Option(1_000_000, min=1, help="Events per chunk (bounds memory)."),
    force: bool = typer.Option(
        False, "--force", help="Replace an existing output folder whole (refused without it)."
    ),
) -> None:
    """Convert an event recording between formats, streaming it in bounded memory."""
    sensor = sensor_option(width, height)
    if dst.suffix:
        check_output_file(dst, "OUT")
    else:
        check_output_dir(dst, "OUT")
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
            force=force,
        )
    wall = time.perf_counter() - wall
    console.print(
        f"{src} ({detect_format(src)}) -> {dst}: {n_events:,} events, {n_gyro:,} gyro samples, "
        f"{wall:.1f} s ({n_events / max(wall, 1e-9) / 1e6:.2f} M events/s)"
    )


STATS_FORMAT = "spikegyro-event-stats/1"


def _windows_of(path: Path, window_us: int, sensor: tuple[int, int] | None) -> list[dict]:
    events = read_recording(path, sensor=sensor).events
    return [stats.window_stats(ev, span) for ev, span in stats.split_windows(events, window_us)]


def compare_stats(
    real: list[Path] = typer.Argument(
        ..., help="Real recordings: event files or Event Camera Dataset folders."
    ),
    sim: Path = typer.Option(
        ..., "--sim", help="A dataset folder (its .h5 files, in DIR or DIR/{train,val,test})."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder: stats.json, sim_vs_real.png."),
    window_ms: float = typer.Option(
        100.0, "--window-ms", min=1.0, help="Cut recordings into windows this long, ms."
    ),
    max_sim_windows: int = typer.Option(
        200, "--max-sim-windows", min=1, help="Use at most this many simulated windows."
    ),
    width: int = typer.Option(None, help="Sensor width of text files (default 240)."),
    height: int = typer.Option(None, help="Sensor height of text files (default 180)."),
) -> None:
    """Compare real recordings' event statistics with a simulated dataset's: event rate, ON/OFF
    balance, inter-event intervals per pixel, hot-pixel share and coverage."""
    from spikegyro.events.plot import stats_figure

    console = Console(stderr=True)
    sensor = sensor_option(width, height)
    check_output_dir(out)
    files = sorted(p for p in Path(sim).rglob("*") if p.suffix.lower() in (".h5", ".hdf5"))
    if not files:
        raise InputError(f"{sim}: no .h5 sequence files; simulate one with `spikegyro simulate`.")
    window_us = round(window_ms * 1000)
    real_windows: dict[str, list[dict]] = {}
    sim_windows: list[dict] = []
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("real recordings", total=len(real))
        for path in real:
            name = recording_name(Path(path))
            real_windows[name] = _windows_of(Path(path), window_us, sensor)
            if not real_windows[name]:
                raise InputError(f"{path}: the file holds no events.")
            bar.advance(task)
        task = bar.add_task("simulated sequences", total=len(files))
        for path in files:
            sim_windows += _windows_of(path, window_us, None)
            bar.advance(task)
            if len(sim_windows) >= max_sim_windows:
                break
    sim_windows = sim_windows[:max_sim_windows]
    result = {
        "format": STATS_FORMAT,
        "window_ms": window_ms,
        "iei_edges_us": stats.IEI_EDGES_US.tolist(),
        "rate_edges_hz": stats.RATE_EDGES_HZ.tolist(),
        "sim": {"dir": str(sim), "files": len(files), **stats.pool(sim_windows)},
        "real": {
            name: {"path": str(path), **stats.pool(ws)}
            for (name, ws), path in zip(real_windows.items(), real, strict=True)
        },
    }
    fig = stats_figure(real_windows, sim_windows, stats.IEI_EDGES_US, stats.RATE_EDGES_HZ,
                       sim_label=f"simulator ({Path(sim).name})")  # fmt: skip
    with atomic_dir(out) as staging:
        (staging / "stats.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
        fig.savefig(staging / "sim_vs_real.png", dpi=90, format="png", metadata={"Software": None})
    table = Table(title=f"median over {window_ms:g} ms windows (5th/95th percentiles: stats.json)")
    for col in ("data", "windows", "events/ms", "ON frac.", "top 1 % share", "coverage",
                "IEI median [ms]"):  # fmt: skip
        table.add_column(col, justify="left" if col == "data" else "right")
    for name, pooled in [("simulator", result["sim"]), *result["real"].items()]:
        keys = ("rate_per_ms", "on_fraction", "top_share", "coverage", "iei_median_us")
        table.add_row(name, str(pooled["windows"]), *(_spread(pooled, key) for key in keys))
    console.print(table)
    console.print(f"wrote {out}/stats.json, {out}/sim_vs_real.png")


def _spread(pooled: dict, key: str) -> str:
    s = pooled["top_share"]["0.01"] if key == "top_share" else pooled[key]
    if not s["n"]:
        return "-"
    scale = 1e-3 if key == "iei_median_us" else 1.0
    return f"{s['median'] * scale:.{1 if key == 'rate_per_ms' else 3}f}"
