"""Prophesee / Metavision recordings: RAW (EVT 2.0 and EVT 3.0) and DAT, decoded from the specs.

Both start with a text header of lines beginning with ``%`` (RAW: ``% evt 3.0``, ``% format
EVT3;height=720;width=1280``, ``% geometry 1280x720``, ..., ``% end``; DAT: ``% Version 2``,
``% Width 640``, ``% Height 480``), which is how they are told apart from text ``.dat`` files.

- EVT 2.0: little-endian 32-bit words, type in bits 28-31. CD_OFF (0) / CD_ON (1): timestamp
  low bits 22-27, x = bits 11-21, y = bits 0-10. EVT_TIME_HIGH (8): bits 0-27 are the
  timestamp's upper 28 bits (t = high · 64 + low, a 34-bit counter, unwrapped here).
- EVT 3.0: little-endian 16-bit words, type in bits 12-15, decoded by a small state machine:
  EVT_ADDR_Y (0) sets y; EVT_ADDR_X (2) emits one event at x (bits 0-10), polarity bit 11;
  VECT_BASE_X (3) sets the base x and polarity; VECT_12 (4) / VECT_8 (5) emit an event at
  base + i for each set bit i of their 12 / 8 valid bits, then advance the base by 12 / 8;
  EVT_TIME_LOW (6) and EVT_TIME_HIGH (8) set the lower and upper 12 bits of a 24-bit time
  (unwrapped: a time-high that goes back by over half its range means the counter wrapped;
  smaller steps back are out-of-order data, put in order later). Others are skipped.
- DAT: after the header, one byte of event type and one of event size (8), then events of
  uint32 timestamp (µs, unwrapped) and uint32 data: x = bits 0-13, y = bits 14-27, polarity
  = bits 28-31.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numba
import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import CameraHeader, EventBlock, ImuBlock, TimeUnwrapper

FORMATS = ("prophesee_raw", "prophesee_dat")
_BLOCK_BYTES = 1 << 23
_HEADER_LIMIT = 1 << 16


def _header_lines(path: Path) -> tuple[list[str], int]:
    """The ``%`` lines and the offset of the first byte after them."""
    lines: list[str] = []
    with open(path, "rb") as f:
        while True:
            start = f.tell()
            if f.read(1) != b"%":
                return lines, start
            f.seek(start)
            line = f.readline(_HEADER_LIMIT)
            text = line.decode("latin-1").strip()
            lines.append(text)
            if text == "% end":
                return lines, f.tell()


def sniff(path: Path, head: bytes) -> str | None:
    """``prophesee_raw`` or ``prophesee_dat`` for a file with a ``%`` header, else None."""
    if not head.startswith(b"%"):
        return None
    text = head.decode("latin-1").lower()
    if re.search(r"^% (evt |format |end)", text, re.M) or path.suffix.lower() == ".raw":
        return "prophesee_raw"
    if re.search(r"^% (version|width|height|date)", text, re.M) or path.suffix.lower() == ".dat":
        return "prophesee_dat"
    return None


def read_header(path: Path, fmt: str) -> CameraHeader:
    """Sensor size, encoding and the data offset from the ``%`` header."""
    lines, offset = _header_lines(path)
    fields: dict[str, str] = {}
    for text in lines:
        key, _, value = text[1:].strip().partition(" ")
        if key:
            fields[key.lower()] = value.strip()
    attrs = {
        f"prophesee_{k}": v
        for k, v in fields.items()
        if k in ("camera_integrator_name", "plugin_name", "serial_number", "date", "version")
    }
    if fmt == "prophesee_dat":
        sensor = None
        if "width" in fields and "height" in fields:
            sensor = (int(fields["width"]), int(fields["height"]))
        size = path.stat().st_size - offset - 2
        if size < 0:
            raise InputError(f"{path}: truncated: the DAT header lacks its event type and size.")
        with open(path, "rb") as f:
            f.seek(offset)
            _, ev_size = f.read(2)
        if ev_size != 8:
            raise InputError(f"{path}: DAT events of {ev_size} bytes; only 8-byte events are read.")
        if size % 8:
            raise InputError(f"{path}: truncated: {size} data bytes are not whole 8-byte events.")
        return CameraHeader(fmt=fmt, sensor=sensor, attrs=attrs, data_offset=offset + 2)
    fmt_field = fields.get("format", "")
    if fmt_field:
        encoding = fmt_field.split(";")[0].strip().lower()
    else:
        encoding = "evt" + fields.get("evt", "").split(".")[0]
    if encoding not in ("evt2", "evt3"):
        raise InputError(
            f"{path}: RAW encoding '{encoding or 'unknown'}' is not supported; EVT 2.0 and "
            "EVT 3.0 are (the header's '% evt' or '% format' line names it)."
        )
    sensor = None
    match = re.search(r"width=(\d+)", fmt_field)
    match_h = re.search(r"height=(\d+)", fmt_field)
    if match and match_h:
        sensor = (int(match.group(1)), int(match_h.group(1)))
    elif "geometry" in fields:
        w, _, h = fields["geometry"].partition("x")
        sensor = (int(w), int(h))
    return CameraHeader(fmt=fmt, sensor=sensor, attrs=attrs, data_offset=offset, encoding=encoding)


def iter_blocks(
    path: Path, header: CameraHeader, *, events: bool = True, imu: bool = True
) -> Iterator[EventBlock | ImuBlock]:
    """Events in file order, a bounded block at a time (these files hold no IMU samples)."""
    if not events:
        return
    if header.fmt == "prophesee_dat":
        yield from _iter_dat(path, header)
    elif header.encoding == "evt2":
        yield from _iter_evt2(path, header)
    else:
        yield from _iter_evt3(path, header)


def _read_words(path: Path, offset: int, dtype: str) -> Iterator[np.ndarray]:
    itemsize = np.dtype(dtype).itemsize
    with open(path, "rb") as f:
        f.seek(offset)
        while True:
            raw = f.read(_BLOCK_BYTES)
            if not raw:
                return
            if len(raw) % itemsize:
                raise InputError(f"{path}: truncated: the data end inside a {itemsize}-byte word.")
            yield np.frombuffer(raw, dtype=dtype)


def _iter_dat(path: Path, header: CameraHeader) -> Iterator[EventBlock]:
    unwrap = TimeUnwrapper(1 << 32)
    for words in _read_words(path, header.data_offset, "<u4"):
        pairs = words.reshape(-1, 2)
        data = pairs[:, 1]
        yield EventBlock(
            x=(data & 0x3FFF).astype(np.int16),
            y=((data >> 14) & 0x3FFF).astype(np.int16),
            t=unwrap(pairs[:, 0]),
            p=((data >> 28) & 1).astype(np.uint8),
        )


def _iter_evt2(path: Path, header: CameraHeader) -> Iterator[EventBlock]:
    unwrap = TimeUnwrapper(1 << 28)
    last_high = np.zeros(1, dtype=np.int64)  # the time-high in force (from earlier blocks)
    for words in _read_words(path, header.data_offset, "<u4"):
        kind = words >> 28
        is_high = kind == 8
        highs = np.concatenate([last_high, unwrap(words[is_high] & 0x0FFFFFFF)])
        last_high = highs[-1:]
        cd = kind <= 1
        w = words[cd]
        high = highs[np.cumsum(is_high)[cd]]
        yield EventBlock(
            x=((w >> 11) & 0x7FF).astype(np.int16),
            y=(w & 0x7FF).astype(np.int16),
            t=(high << 6) | ((w >> 22) & 0x3F).astype(np.int64),
            p=kind[cd].astype(np.uint8),
        )


@numba.njit(cache=True, nogil=True)
def _decode_evt3(words, state, fill, x, y, t, p):  # pragma: no cover - compiled
    """Run the EVT 3.0 state machine over ``words``; count events, and store them if ``fill``.

    ``state`` = [y, base_x, polarity, time_low, time_high, time_high_loops · 2^24, seen_high],
    carried from block to block. Returns the number of events.
    """
    cur_y, base_x, pol, t_low, t_high, loops, seen = state
    n = 0
    for i in range(words.size):
        w = np.int64(words[i])
        kind = w >> 12
        if kind == 0x0:
            cur_y = w & 0x7FF
        elif kind == 0x2:
            if fill:
                x[n] = w & 0x7FF
                y[n] = cur_y
                t[n] = loops + (t_high << 12) + t_low
                p[n] = (w >> 11) & 1
            n += 1
        elif kind == 0x3:
            base_x = w & 0x7FF
            pol = (w >> 11) & 1
        elif kind == 0x4 or kind == 0x5:
            width = 12 if kind == 0x4 else 8
            for b in range(width):
                if (w >> b) & 1:
                    if fill:
                        x[n] = base_x + b
                        y[n] = cur_y
                        t[n] = loops + (t_high << 12) + t_low
                        p[n] = pol
                    n += 1
            base_x += width
        elif kind == 0x6:
            t_low = w & 0xFFF
        elif kind == 0x8:
            high = w & 0xFFF
            if seen and t_high - high > 2048:  # back by over half the period: a wrap
                loops += 1 << 24
            t_high = high
            seen = 1
    if fill:
        state[0] = cur_y
        state[1] = base_x
        state[2] = pol
        state[3] = t_low
        state[4] = t_high
        state[5] = loops
        state[6] = seen
    return n


def _iter_evt3(path: Path, header: CameraHeader) -> Iterator[EventBlock]:
    state = np.zeros(7, dtype=np.int64)
    for words in _read_words(path, header.data_offset, "<u2"):
        n = _decode_evt3(words, state.copy(), False, *(np.empty(0, d) for d in _EVT3_DTYPES))
        out = [np.empty(n, dtype=d) for d in _EVT3_DTYPES]
        _decode_evt3(words, state, True, *out)
        yield EventBlock(*out)


_EVT3_DTYPES = (np.int16, np.int16, np.int64, np.uint8)
