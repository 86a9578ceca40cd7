"""Read speed of every event format through ``iter_event_chunks``, as a ratio to our HDF5 reader.

One synthetic recording (uniform random pixels, 1 µs-resolution timestamps, sorted) is written
in each format, then streamed back in 1 M-event chunks; the best of ``--repeats`` runs after
one warm-up run counts.
Ratios are measured in the same run, so they hold on a loaded machine where absolute rates do
not. Formats whose optional writer (faery, rosbags) is missing are left out.

    PYTHONPATH=. .venv/bin/python bench/formats.py --events 2000000
"""

from __future__ import annotations

import argparse
import importlib.util
import struct
import tempfile
import time
from pathlib import Path

import numpy as np

from spikegyro.events import EventArray, Recording, write_recording
from spikegyro.events.convert import convert
from spikegyro.events.io import iter_event_chunks


def synthetic(n: int, seed: int = 0) -> EventArray:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, n // 2, n))  # about 2 M events/s
    return EventArray.from_arrays(
        rng.integers(0, 640, n), rng.integers(0, 480, n), t, rng.integers(0, 2, n), 640, 480
    )


def write_jaer2(path: Path, ev: EventArray) -> None:
    # DAVIS address layout (see spikegyro.events.jaer); jAER counts y from the bottom row.
    header = b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.DAVIS640\r\n"
    addr = ((479 - ev.y.astype(np.uint32)) << 22) | (ev.x.astype(np.uint32) << 12)
    addr |= ev.p.astype(np.uint32) << 11
    table = np.column_stack([addr, ev.t.astype(np.uint32)]).astype(">u4")
    path.write_bytes(header + table.tobytes())


def write_rosbag(path: Path, ev: EventArray, per_message: int = 20_000) -> None:
    from rosbags.rosbag1 import Writer

    from spikegyro.events.rosbag import _ROS1_EVENT, EVENT_ARRAY, typestore

    store = typestore()
    with Writer(path) as writer:
        conn = writer.add_connection("/dvs/events", EVENT_ARRAY, typestore=store)
        for seq, i in enumerate(range(0, len(ev), per_message)):
            part = ev[i : i + per_message]
            rows = np.empty(len(part), dtype=_ROS1_EVENT)
            rows["x"], rows["y"], rows["p"] = part.x, part.y, part.p
            rows["sec"], rows["nsec"] = part.t // 1_000_000, part.t % 1_000_000 * 1000
            sec, nsec = int(part.t[0]) // 1_000_000, int(part.t[0]) % 1_000_000 * 1000
            head = struct.pack("<IIII3sIII", seq, sec, nsec, 3, b"cam", 480, 640, len(part))
            writer.write(conn, int(part.t[0]) * 1000 + 1, head + rows.tobytes())


def write_evt2(path: Path, ev: EventArray) -> None:
    import faery

    events = np.empty(len(ev), dtype=faery.EVENTS_DTYPE)
    events["t"], events["x"], events["y"], events["on"] = ev.t, ev.x, ev.y, ev.p.astype(bool)
    with faery.extension.evt.Encoder(str(path), "evt2", False, (640, 480), True) as encoder:
        encoder.write({"events": events})


def read_rate(path: Path, repeats: int) -> tuple[float, int]:
    best = float("inf")
    for _ in range(repeats + 1):  # the first run is a warm-up (imports, numba cache, page cache)
        start = time.perf_counter()
        chunks = iter_event_chunks(path, sensor=(640, 480), chunk_events=1_000_000)
        n = sum(len(c) for c in chunks)
        if _:
            best = min(best, time.perf_counter() - start)
    return n / best / 1e6, n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    ev = synthetic(args.events)
    have_faery = importlib.util.find_spec("faery") is not None
    have_aedat = importlib.util.find_spec("aedat") is not None
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = {"hdf5 (ours)": write_recording(folder / "rec.h5", Recording(ev))}
        files["npz"] = write_recording(folder / "rec.npz", Recording(ev))
        files["events.txt"] = write_recording(folder / "rec.txt", Recording(ev))
        write_jaer2(folder / "rec.aedat", ev)
        files["jAER AEDAT 2.0"] = folder / "rec.aedat"
        if have_faery:
            for name, suffix in (("Prophesee EVT 3.0", ".raw"), ("Prophesee DAT", ".dat")):
                convert(files["hdf5 (ours)"], folder / f"rec{suffix}")
                files[name] = folder / f"rec{suffix}"
            write_evt2(folder / "rec2.raw", ev)
            files["Prophesee EVT 2.0"] = folder / "rec2.raw"
            if have_aedat:
                convert(files["hdf5 (ours)"], folder / "rec.aedat4")
                files["AEDAT 4 (LZ4)"] = folder / "rec.aedat4"
        if importlib.util.find_spec("rosbags") is not None:
            write_rosbag(folder / "rec.bag", ev)
            files["ROS 1 bag"] = folder / "rec.bag"
        rates = {}
        for name, path in files.items():
            rates[name], n = read_rate(path, args.repeats)
            assert n == len(ev), (name, n)
        base = rates["hdf5 (ours)"]
        print(f"{len(ev):,} events, best of {args.repeats}; read with iter_event_chunks")
        print("| format | file MB | M events/s | vs HDF5 |\n|---|---:|---:|---:|")
        for name, path in files.items():
            size = path.stat().st_size / 1e6
            print(f"| {name} | {size:.1f} | {rates[name]:.1f} | {rates[name] / base:.2f} |")


if __name__ == "__main__":
    main()
