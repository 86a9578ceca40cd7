"""jAER / cAER AEDAT 2.0 and 3.1 files (older DAVIS recordings), with their IMU's gyro samples.

AEDAT 2.0 (jAER): a text header of ``#`` lines (``#!AER-DAT2.0`` first, ``# AEChip: ...``), then
big-endian records of (uint32 address, int32 timestamp in µs). For the DAVIS chips, address
bit 31 = 0 is a DVS event: x = bits 12-21, y = bits 22-30 counted from the *bottom* row (flipped
here so that y points down), polarity = bit 11 (1 = ON); bit 10 marks an external trigger
(skipped). Bit 31 = 1 is an APS sample (skipped) unless bits 10-11 = 3: an IMU word, channel in
bits 28-30 (0-2 accelerometer, 3 temperature, 4-6 gyro x, y, z) and an int16 value in bits
12-27, seven words per sample; the gyro reads 32.8 LSB per deg/s (±1000 deg/s full scale).
The 32-bit timestamps wrap every 2^32 µs (71.6 min); wraps are undone.

AEDAT 3.1 (cAER / DV's predecessor): a header of ``#`` lines ending with ``#!END-HEADER``, then
little-endian packets: a 28-byte header (int16 type, int16 source, int32 event size, int32
timestamp offset, int32 timestamp overflow, int32 capacity, int32 number, int32 valid) and
capacity x size bytes of events. Polarity events (type 1, 8 bytes): uint32 data (bit 0 valid,
bit 1 polarity, y = bits 2-16, x = bits 17-31, origin top left), int32 timestamp. IMU6 events
(type 3, 36 bytes): uint32 info (bit 0 valid), int32 timestamp, then float32 accelerometer x, y, z
(g), gyro x, y, z (deg/s) and temperature. Full timestamps are overflow · 2^31 + timestamp.
Other packet types (frames, triggers, ...) are skipped.

A file cut inside its last record or packet is read up to it, with a warning; one cut inside its
header (jAER writes headers of hundreds of kB) holds no data and is refused.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import CameraHeader, EventBlock, ImuBlock, TimeUnwrapper
from spikegyro.events.prophesee import warn_truncated

FORMATS = ("jaer2", "jaer3")
GYRO_LSB_PER_DPS = 32.8
_BLOCK_RECORDS = 1 << 20
_CHIP_SIZES = (
    ("davis240", (240, 180)),
    ("davis346", (346, 260)),
    ("davis640", (640, 480)),
    ("davis208", (208, 192)),
    ("davis128", (128, 128)),
    ("dvxplorer", (640, 480)),
)
_HEADER_LIMIT = 1 << 24


def sniff(path: Path, head: bytes) -> str | None:
    """``jaer2`` or ``jaer3`` from the first bytes, else None."""
    if head.startswith((b"#!AER-DAT2", b"#!AER-DAT1")):
        return "jaer2"
    if head.startswith(b"#!AER-DAT3"):
        return "jaer3"
    return None


def _chip_size(name: str) -> tuple[int, int] | None:
    key = name.lower().replace("_", "")
    return next((size for chip, size in _CHIP_SIZES if chip in key), None)


def _header_lines(path: Path) -> tuple[list[str], int, bool]:
    """The ``#`` lines, the offset of the first data byte, and whether the header is whole.

    AEDAT 2.0 headers end at ``#End Of ASCII Header`` or the first non-``#`` line, AEDAT 3.1
    ones at ``#!END-HEADER``.
    """
    lines: list[str] = []
    ended = True
    with open(path, "rb") as f:
        while True:
            start = f.tell()
            line = f.readline(_HEADER_LIMIT)
            if not line:
                return lines, start, _whole_at_eof(lines, ended)
            if not line.startswith(b"#"):
                return lines, start, True
            ended = line.endswith(b"\n")
            text = line.decode("latin-1").strip()
            lines.append(text)
            if text.startswith(("#!END-HEADER", "#End Of ASCII Header")):
                return lines, f.tell(), True


def _whole_at_eof(lines: list[str], ended: bool) -> bool:
    """Whether a header that runs to the end of the file is a recording without data, rather
    than a file cut inside its header: its last line ended, jAER's ``<preferences>`` block
    closed, and it is not AEDAT 3.1 (whose header has an end line)."""
    text = "\n".join(lines)
    prefs_open = "<preferences" in text and "</preferences>" not in text
    return bool(lines) and ended and not prefs_open and not lines[0].startswith("#!AER-DAT3")


def read_header(path: Path, fmt: str) -> CameraHeader:
    """Parse the ``#`` header: version, chip (hence sensor size) and where the data start."""
    lines, offset, whole = _header_lines(path)
    if not whole:
        raise InputError(
            f"{path}: truncated: the file ends inside its text header, before any data; copy "
            "the whole recording again."
        )
    version = lines[0][len("#!AER-DAT") :] if lines else "?"
    if fmt == "jaer2" and not version.startswith("2"):
        raise InputError(
            f"{path}: AEDAT {version} is not supported; AEDAT 2.0 and 3.1 are (convert AEDAT 1 "
            "files with jAER)."
        )
    chip = ""
    for text in lines:
        match = re.match(r"#\s*(?:AEChip:|-?Source \d+:)\s*(\S+)", text)
        if match:
            chip = match.group(1).rsplit(".", 1)[-1]
            break
    if fmt == "jaer2" and chip and _chip_size(chip) is None:
        raise InputError(
            f"{path}: chip '{chip}' is not supported; only DAVIS address layouts are read."
        )
    attrs = {"camera": chip, "aedat_version": version} if chip else {"aedat_version": version}
    return CameraHeader(fmt=fmt, sensor=_chip_size(chip), attrs=attrs, data_offset=offset)


def iter_blocks(
    path: Path, header: CameraHeader, *, events: bool = True, imu: bool = True
) -> Iterator[EventBlock | ImuBlock]:
    """Events and gyro samples in file order, a bounded block at a time."""
    if header.fmt == "jaer2":
        yield from _iter_aedat2(path, header, events, imu)
    else:
        yield from _iter_aedat3(path, header, events, imu)


def _iter_aedat2(
    path: Path, header: CameraHeader, events: bool, imu: bool
) -> Iterator[EventBlock | ImuBlock]:
    height = (header.sensor or (240, 180))[1]
    unwrap = TimeUnwrapper(1 << 32)
    carry = np.zeros((0, 3), dtype=np.int64)  # IMU words of a sample split across blocks
    with open(path, "rb") as f:
        f.seek(header.data_offset)
        while True:
            raw = f.read(8 * _BLOCK_RECORDS)
            if len(raw) % 8:
                warn_truncated(path, len(raw) % 8, "8-byte record")
                raw = raw[: len(raw) - len(raw) % 8]
            if not raw:
                break
            words = np.frombuffer(raw, dtype=">u4").reshape(-1, 2)
            addr = words[:, 0]
            t = unwrap(words[:, 1])
            dvs = (addr >> 31) == 0
            if events:
                keep = dvs & ((addr >> 10) & 1 == 0)
                a = addr[keep]
                yield EventBlock(
                    x=((a >> 12) & 0x3FF).astype(np.int16),
                    y=(height - 1 - ((a >> 22) & 0x1FF).astype(np.int16)).astype(np.int16),
                    t=t[keep],
                    p=((a >> 11) & 1).astype(np.uint8),
                )
            if imu:
                sel = ~dvs & (((addr >> 10) & 3) == 3)
                a = addr[sel]
                value = ((a >> 12) & 0xFFFF).astype(np.uint16).view(np.int16)
                rows = np.column_stack([(a >> 28) & 7, value, t[sel]]).astype(np.int64)
                block, carry = _imu_samples(np.concatenate([carry, rows]))
                if block is not None:
                    yield block


def _imu_samples(rows: np.ndarray) -> tuple[ImuBlock | None, np.ndarray]:
    """Whole 7-word IMU samples from (channel, value, t) rows; the unfinished tail is carried."""
    channel = rows[:, 0]
    n = len(rows)
    starts = np.flatnonzero(channel[: max(n - 6, 0)] == 0)
    whole = np.ones(starts.size, dtype=bool)
    for k in range(1, 7):
        whole &= channel[starts + k] == k
    starts = starts[whole]
    tail_start = np.flatnonzero(channel == 0)
    tail_start = tail_start[tail_start > n - 7]
    carry = rows[tail_start[0] :] if tail_start.size else rows[:0]
    if not starts.size:
        return None, carry
    gyro = np.stack([rows[starts + k, 1] for k in (4, 5, 6)], axis=1)
    omega = np.radians(gyro / GYRO_LSB_PER_DPS)
    return ImuBlock(t=rows[starts, 2], omega=omega), carry


_PACKET_HEADER = np.dtype(
    [
        ("type", "<i2"),
        ("source", "<i2"),
        ("size", "<i4"),
        ("ts_offset", "<i4"),
        ("ts_overflow", "<i4"),
        ("capacity", "<i4"),
        ("number", "<i4"),
        ("valid", "<i4"),
    ]
)
_POLARITY = np.dtype([("data", "<u4"), ("t", "<i4")])
_IMU6 = np.dtype([("info", "<u4"), ("t", "<i4"), ("values", "<f4", (7,))])


def _iter_aedat3(
    path: Path, header: CameraHeader, events: bool, imu: bool
) -> Iterator[EventBlock | ImuBlock]:
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(header.data_offset)
        while True:
            raw = f.read(_PACKET_HEADER.itemsize)
            if not raw:
                return
            if len(raw) < _PACKET_HEADER.itemsize:
                warn_truncated(path, len(raw), "packet header")
                return
            h = np.frombuffer(raw, dtype=_PACKET_HEADER)[0]
            nbytes = int(h["capacity"]) * int(h["size"])
            if h["capacity"] < 0 or h["size"] < 0 or h["number"] > h["capacity"]:
                raise InputError(f"{path}: a packet header at byte {f.tell() - 28} is corrupt.")
            kind = int(h["type"])
            wanted = (kind == 1 and events) or (kind == 3 and imu)
            if not wanted:
                end = f.tell() + nbytes
                if end > size:
                    warn_truncated(path, size - f.tell() + 28, "packet")
                    return
                f.seek(end)
                continue
            data = f.read(nbytes)
            if len(data) < nbytes:
                warn_truncated(path, len(data) + 28, "packet")
                return
            overflow = np.int64(h["ts_overflow"]) << 31
            number = int(h["number"])
            if kind == 1:
                if h["size"] != _POLARITY.itemsize:
                    raise InputError(f"{path}: polarity events of {h['size']} bytes, expected 8.")
                ev = np.frombuffer(data, dtype=_POLARITY, count=number)
                ev = ev[(ev["data"] & 1) == 1]
                d = ev["data"]
                yield EventBlock(
                    x=((d >> 17) & 0x7FFF).astype(np.int16),
                    y=((d >> 2) & 0x7FFF).astype(np.int16),
                    t=ev["t"].astype(np.int64) + overflow,
                    p=((d >> 1) & 1).astype(np.uint8),
                )
            else:
                if h["size"] != _IMU6.itemsize:
                    raise InputError(f"{path}: IMU6 events of {h['size']} bytes, expected 36.")
                ev = np.frombuffer(data, dtype=_IMU6, count=number)
                ev = ev[(ev["info"] & 1) == 1]
                yield ImuBlock(
                    t=ev["t"].astype(np.int64) + overflow,
                    omega=np.radians(ev["values"][:, 3:6].astype(np.float64)),
                )
