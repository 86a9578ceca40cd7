"""iniVation AEDAT 4 files (DV software; DAVIS, DVXplorer), through the ``aedat`` package.

AEDAT 4 is a ``#!AER-DAT4.0`` line, a flatbuffers header (compression, an XML description of
the streams) and packets of flatbuffers, often LZ4- or zstd-compressed. The ``aedat`` package
(a Rust decoder with Linux/macOS/Windows wheels, extra ``spikegyro[aedat4]``) decodes a packet
at a time, so memory stays bounded. Events come from the first event stream (``t`` µs, x, y,
``on``), gyro samples from the first IMU stream (DV records the gyroscope in deg/s, in the IMU
chip's axes: give ``--imu-to-camera`` to rotate them into the camera frame). Frames and
triggers are skipped.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import CameraHeader, EventBlock, ImuBlock, optional_import

FORMATS = ("aedat4",)
EXTRA = "aedat4"


def sniff(path: Path, head: bytes) -> str | None:
    """``aedat4`` from the magic line, else None."""
    return "aedat4" if head.startswith(b"#!AER-DAT4") else None


def _decoder(path: Path) -> Any:
    aedat = optional_import("aedat", EXTRA, path)
    try:
        return aedat.Decoder(str(path))
    except Exception as exc:  # the Rust decoder raises plain exceptions on bad headers
        raise InputError(f"{path}: not a readable AEDAT 4 file ({exc}).") from None


def _streams(decoder: Any) -> tuple[int | None, int | None, tuple[int, int] | None]:
    events_id = imu_id = None
    sensor = None
    for sid, info in sorted(decoder.id_to_stream().items()):
        if info.get("type") == "events" and events_id is None:
            events_id, sensor = sid, (int(info["width"]), int(info["height"]))
        elif info.get("type") == "imus" and imu_id is None:
            imu_id = sid
    return events_id, imu_id, sensor


def read_header(path: Path, fmt: str) -> CameraHeader:
    """Sensor size of the first event stream."""
    _, _, sensor = _streams(_decoder(path))
    return CameraHeader(fmt=fmt, sensor=sensor)


def iter_blocks(
    path: Path, header: CameraHeader, *, events: bool = True, imu: bool = True
) -> Iterator[EventBlock | ImuBlock]:
    """Event and IMU packets in file order."""
    decoder = _decoder(path)
    events_id, imu_id, _ = _streams(decoder)
    try:
        for packet in decoder:
            sid = packet["stream_id"]
            if events and sid == events_id and "events" in packet:
                ev = packet["events"]
                yield EventBlock(
                    x=ev["x"].astype(np.int16),
                    y=ev["y"].astype(np.int16),
                    t=ev["t"].astype(np.int64),
                    p=ev["on"].astype(np.uint8),
                )
            elif imu and sid == imu_id and "imus" in packet:
                s = packet["imus"]
                gyro = np.column_stack([s["gyroscope_x"], s["gyroscope_y"], s["gyroscope_z"]])
                yield ImuBlock(t=s["t"].astype(np.int64), omega=np.radians(gyro.astype(np.float64)))
    except InputError:
        raise
    except Exception as exc:  # truncated or corrupt packets
        raise InputError(f"{path}: a corrupt or truncated AEDAT 4 packet ({exc}).") from None
