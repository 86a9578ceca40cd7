"""Latency of ``predict`` on a live stream: a real recording served at its own pace in 5 ms
packets by dv-processing's network server (spikegyro.events.replay), read by
``spikegyro predict dv://... --out -`` pinned to one core.

For each estimate (CMax, 100 Hz) the latency is the wall time at which its CSV line reached this
script minus the wall time at which the packet holding the last event it uses (the last event
at or before its time) was sent. The same recording run from the file in the same run is the
baseline: its estimates must be identical, and its CPU time per second of events is what one
core needs to keep up. Needs spikegyro[live].

    python bench/live.py [EVENTS] [--intrinsics 245 245 120 90] [--core 1] [--figure latency.png]
        [--reference offline.csv]

``--reference``: a prediction file of the same recording (e.g. ``predict --method cmax
--offline``); the estimates' mean Euclidean difference from it (interpolated at their times,
from 0.5 s into the stream on) is printed too.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spikegyro.events.io import read_recording
from spikegyro.events.replay import start_replay
from spikegyro.stream.writer import read_predictions

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "real" / "rueckauer2016_translBoxes" / "events.txt"
PACKET_US = 5000


def spikegyro(core: int, *args: str) -> list[str]:
    """The command line of ``spikegyro`` pinned to ``core``."""
    return ["taskset", "-c", str(core), sys.executable, "-m", "spikegyro", *args]


def run_live(path: Path, core: int, options: list[str], log: Path) -> tuple[list, list, str]:
    """Serve ``path`` and read it live; returns (CSV lines, their arrival times, stderr)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = start_replay(path, f"dv://127.0.0.1:{port}", PACKET_US, sent_log=log)
    command = spikegyro(core, "predict", f"dv://127.0.0.1:{port}", "--out", "-", *options)
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines, arrived = [], []
    for line in proc.stdout:
        arrived.append(time.time())
        lines.append(line)
    err = proc.stderr.read()
    proc.wait()
    server.join(30)
    return lines, arrived, err


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("events", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--intrinsics", nargs=4, default=["245", "245", "120", "90"])
    parser.add_argument("--core", type=int, default=1, help="the core predict runs on")
    parser.add_argument("--figure", type=Path, help="Plot each estimate's latency here (PNG).")
    parser.add_argument("--reference", type=Path, help="Prediction file to compare with.")
    args = parser.parse_args()
    options = ["--intrinsics", *args.intrinsics]
    # This script and the replay server (a child, which inherits it) keep off predict's core.
    others = os.sched_getaffinity(0) - {args.core}
    if others:
        os.sched_setaffinity(0, others)
    with tempfile.TemporaryDirectory() as tmp:
        file_csv, log = Path(tmp) / "file.csv", Path(tmp) / "sent.npy"
        started, cpu = time.time(), os.times()
        subprocess.run(spikegyro(args.core, "predict", str(args.events), "--method", "cmax",
                                 "--out", str(file_csv), *options), check=True,
                       capture_output=True)  # fmt: skip
        after = os.times()
        file_cpu = after.children_user + after.children_system
        file_cpu -= cpu.children_user + cpu.children_system
        file_wall = time.time() - started
        lines, arrived, err = run_live(args.events, args.core, options, log)
        sent = np.load(log)
        want = file_csv.read_text().splitlines(keepends=True)
        ours = read_predictions(file_csv)
    ev = read_recording(args.events).events
    rows = np.array([float(line.split(",")[0]) for line in lines[1:]])
    t_us = np.rint(rows * 1e6).astype(np.int64)
    last_event = ev.t[np.searchsorted(ev.t, t_us, side="right") - 1]
    packet = (last_event - ev.t[0]) // PACKET_US
    latency_ms = (np.array(arrived[1:]) - sent[packet]) * 1000
    seconds = (ev.t[-1] - ev.t[0]) / 1e6
    print(f"{args.events} ({len(ev):,} events, {seconds:.2f} s), {PACKET_US // 1000} ms packets, "
          f"predict on core {args.core}")  # fmt: skip
    print(
        f"file run (baseline): {len(want) - 1} estimates, {file_wall:.1f} s wall, "
        f"{file_cpu / seconds:.2f} CPU-seconds per second of events (start-up included)"
    )
    print(f"live: {len(lines) - 1} estimates, identical to the file's: {lines == want}")
    p50, p95, p99 = np.percentile(latency_ms, [50, 95, 99])
    print(
        f"latency from the send of the last event used to the estimate's line: median "
        f"{p50:.1f} ms, 95th percentile {p95:.1f} ms, 99th {p99:.1f} ms, max "
        f"{latency_ms.max():.1f} ms; 95th percentile / 20 ms target = {p95 / 20:.2f}"
    )
    print("\n".join(line for line in err.splitlines() if "behind" in line or "estimates (" in line))
    if args.reference:
        print(difference(ours, args.reference, ev.t[0]))
    if args.figure:
        plot_latency(args.figure, (t_us - ev.t[0]) / 1e6, latency_ms, args.events.name)


def difference(ours: dict[str, np.ndarray], reference: Path, t0_us: int) -> str:
    """The mean Euclidean difference (deg/s) of prediction arrays ``ours`` (``read_predictions``)
    from the file ``reference``, from 0.5 s into the stream on."""
    ref = read_predictions(reference)
    keep = ours["t_us"] >= t0_us + 500_000
    t_us = ours["t_us"][keep]
    truth = np.stack([np.interp(t_us, ref["t_us"], ref["omega"][:, k]) for k in range(3)], 1)
    gap = np.degrees(np.linalg.norm(ours["omega"][keep] - truth, axis=1))
    return (
        f"mean Euclidean difference from {reference.name}: {gap.mean():.2f} deg/s "
        f"({keep.sum()} estimates)"
    )


def plot_latency(path: Path, t_s: np.ndarray, latency_ms: np.ndarray, name: str) -> None:
    """Each estimate's latency (ms) against its time in the stream (s), with the target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3))
    ax.plot(t_s, latency_ms, ".", ms=3, label="estimate")
    ax.axhline(20, color="k", lw=0.8, ls="--", label="20 ms target (95th percentile)")
    ax.set(xlabel="stream time (s)", ylabel="latency (ms)", yscale="log",
           title=f"predict dv://... on one core: {name}")  # fmt: skip
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
