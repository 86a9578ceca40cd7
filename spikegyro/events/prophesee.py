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
  smaller steps back are out-of-order data, put in order later). Events before the first
  TIME_HIGH and TIME_LOW have no known time and are dropped. Some writers (expelliarmus) emit
  TIME_HIGH once and let TIME_LOW wrap: such a wrap advances the time by 4096 µs, with a
  warning; conformant streams never do this. EXT_TRIGGER (0xA, level in bit 0) words are
  counted (as in EVT 2.0), others are skipped.
- DAT: after the header, one byte of event type and one of event size (8), then events of
  uint32 timestamp (µs, unwrapped) and uint32 data: x = bits 0-13, y = bits 14-27, polarity
  = bits 28-31.

The sensor size is the one the header states (``% format``, ``% geometry``, ``% width`` and
``% height``), else the one its plugin name, sensor name or system ID implies, as Metavision maps
them (older Metavision headers name only these), else, with a warning, the smallest known
Prophesee sensor that holds every event. A file cut inside its last word is read up to it, with
a warning.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numba
import numpy as np

from spikegyro.errors import InputError, InputWarning
from spikegyro.events.blocks import CameraHeader, EventBlock, ImuBlock, TimeUnwrapper

FORMATS = ("prophesee_raw", "prophesee_dat")
_BLOCK_BYTES = 1 << 23
_HEADER_LIMIT = 1 << 16

SENSORS: dict[str, tuple[int, int]] = {
    "ATIS": (304, 240),
    "GenX320": (320, 320),
    "Gen3 VGA": (640, 480),
    "Gen4 HD": (1280, 720),
}
"""Prophesee sensors by name: (width, height) in pixels."""

# Metavision's system IDs (the header's ``system_ID``) of the boards whose sensor is known.
_SYSTEM_IDS: dict[int, str] = {
    **dict.fromkeys(
        (0x15, 0x17, 0x19, 0x1C, 0x1D, 0x21, 0x22, 0x23, 0x28, 0x29, 0x97, 0x99, 0xA1, 0xA2),
        "Gen3 VGA",
    ),
    **dict.fromkeys(
        (0x1A, 0x1E, 0x1F, 0x20, 0x27, 0x2E, 0x30, 0x31, 0x32, 0x3A, 0x42, 0x9A), "Gen4 HD"
    ),
    **dict.fromkeys((0x3B, 0x40), "GenX320"),
}
# Plugin and sensor names (``plugin_name hal_plugin_gen41_evk3``, ``sensor_name IMX636``).
_NAME_PATTERNS = (
    (re.compile(r"genx ?320"), "GenX320"),
    (re.compile(r"gen ?3"), "Gen3 VGA"),
    (re.compile(r"gen ?4|imx636"), "Gen4 HD"),
)
_GENERATIONS = {"3": "Gen3 VGA", "4": "Gen4 HD", "320": "GenX320"}


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


def _stated_size(fields: dict[str, str]) -> tuple[int, int] | None:
    """The size the header states: ``% format ...;height=H;width=W``, ``% geometry WxH`` or
    ``% width W`` / ``% height H``."""
    fmt = fields.get("format", "")
    width, height = re.search(r"width=(\d+)", fmt), re.search(r"height=(\d+)", fmt)
    if width and height:
        return int(width.group(1)), int(height.group(1))
    geometry = re.fullmatch(r"(\d+)\s*x\s*(\d+)", fields.get("geometry", ""))
    if geometry:
        return int(geometry.group(1)), int(geometry.group(2))
    if fields.get("width", "").isdigit() and fields.get("height", "").isdigit():
        return int(fields["width"]), int(fields["height"])
    return None


def _named_sensor(fields: dict[str, str]) -> tuple[str, str] | None:
    """(sensor name, the header field that names it), from the plugin or sensor name, the
    sensor generation or the system ID, as Metavision maps them."""
    for key in ("sensor_name", "plugin_name"):
        value = fields.get(key, "").lower()
        for pattern, name in _NAME_PATTERNS:
            if pattern.search(value):
                return name, f"{key} {fields[key]}"
    generation = fields.get("sensor_generation", "").split(".")[0]
    if generation in _GENERATIONS:
        return _GENERATIONS[generation], f"sensor_generation {fields['sensor_generation']}"
    system_id = fields.get("system_id", "")
    if system_id.isdigit() and int(system_id) in _SYSTEM_IDS:
        return _SYSTEM_IDS[int(system_id)], f"system_ID {system_id}"
    return None


def _header_sensor(fields: dict[str, str], attrs: dict[str, Any]) -> tuple[int, int] | None:
    """The size the header states or names (recording in ``attrs`` what it was inferred from)."""
    size = _stated_size(fields)
    if size is None:
        named = _named_sensor(fields)
        if named is not None:
            size = SENSORS[named[0]]
            attrs["sensor_size_from"] = f"{named[1]} ({named[0]}, {size[0]} x {size[1]})"
    return size


def smallest_sensor(max_x: int, max_y: int) -> tuple[str, tuple[int, int]] | None:
    """The known sensor of least area that holds pixel (max_x, max_y), or None."""
    fits = [(w * h, name, (w, h)) for name, (w, h) in SENSORS.items() if max_x < w and max_y < h]
    return (min(fits)[1], min(fits)[2]) if fits else None


def _guess_sensor(path: Path, header: CameraHeader) -> tuple[int, int]:
    """Where nothing names the sensor: the smallest known sensor that holds every event (a
    pass over the file), with a warning."""
    max_x = max_y = -1
    for block in iter_blocks(path, header, imu=False):
        if len(block):
            max_x, max_y = max(max_x, int(block.x.max())), max(max_y, int(block.y.max()))
    fit = smallest_sensor(max_x, max_y)
    name, size = fit if fit else ("the events' extent", (max_x + 1, max_y + 1))
    warnings.warn(
        f"{path}: the header does not name the sensor; assuming {size[0]} x {size[1]} px "
        f"({name}, the smallest that holds every event); pass --width and --height to override.",
        InputWarning,
        stacklevel=2,
    )
    return size


def _fields(lines: list[str]) -> dict[str, str]:
    fields: dict[str, str] = {}
    for text in lines:
        key, _, value = text[1:].strip().partition(" ")
        if key:
            fields[key.lower()] = value.strip()
    return fields


def read_header(path: Path, fmt: str) -> CameraHeader:
    """Sensor size, encoding and the data offset from the ``%`` header.

    The size is the one the header states, else the one its plugin name, sensor name or system
    ID implies (recorded in the ``sensor_size_from`` attribute); where nothing names the sensor,
    the header's ``guess_sensor`` finds the smallest known sensor that holds every event.
    """
    lines, offset = _header_lines(path)
    fields = _fields(lines)
    attrs: dict[str, Any] = {
        f"prophesee_{k}": v
        for k, v in fields.items()
        if k in ("camera_integrator_name", "plugin_name", "serial_number", "date", "version")
    }
    sensor = _header_sensor(fields, attrs)
    if fmt == "prophesee_dat":
        header = _dat_header(path, offset, sensor, attrs)
    else:
        header = CameraHeader(
            fmt=fmt,
            sensor=sensor,
            attrs=attrs,
            data_offset=offset,
            encoding=_encoding(path, fields),
        )
    if sensor is None:
        header = replace(header, guess_sensor=lambda: _guess_sensor(path, header))
    return header


def _encoding(path: Path, fields: dict[str, str]) -> str:
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
    return encoding


def _dat_header(
    path: Path, offset: int, sensor: tuple[int, int] | None, attrs: dict[str, Any]
) -> CameraHeader:
    size = path.stat().st_size - offset - 2
    if size < 0:
        raise InputError(f"{path}: truncated: the DAT header lacks its event type and size.")
    with open(path, "rb") as f:
        f.seek(offset)
        _, ev_size = f.read(2)
    if ev_size != 8:
        raise InputError(f"{path}: DAT events of {ev_size} bytes; only 8-byte events are read.")
    return CameraHeader(fmt="prophesee_dat", sensor=sensor, attrs=attrs, data_offset=offset + 2)


def iter_blocks(
    path: Path, header: CameraHeader, *, events: bool = True, imu: bool = True
) -> Iterator[EventBlock | ImuBlock]:
    """Events in file order, a bounded block at a time (these files hold no IMU samples).

    Once the file is read, external trigger counts (RAW files) are added to ``header.attrs``
    as ``triggers_rising`` / ``triggers_falling``.
    """
    if not events:
        return
    if header.fmt == "prophesee_dat":
        yield from _iter_dat(path, header)
    elif header.encoding == "evt2":
        yield from _iter_evt2(path, header)
    else:
        decoder = Evt3Decoder(str(path))
        for words in _read_words(path, header.data_offset, "<u2"):
            yield decoder.decode(words)
        decoder.finish(header.attrs)


def _read_words(path: Path, offset: int, dtype: str) -> Iterator[np.ndarray]:
    """The data as whole words; a partial last word (a cut file) is left out, with a warning."""
    itemsize = np.dtype(dtype).itemsize
    with open(path, "rb") as f:
        f.seek(offset)
        while True:
            raw = f.read(_BLOCK_BYTES)
            if len(raw) % itemsize:
                warn_truncated(path, len(raw) % itemsize, f"{itemsize}-byte word")
                raw = raw[: len(raw) - len(raw) % itemsize]
            if not raw:
                return
            yield np.frombuffer(raw, dtype=dtype)


def warn_truncated(path: Path, extra: int, unit: str) -> None:
    """Warn that a file ends ``extra`` bytes into a ``unit`` (its writer was cut off)."""
    warnings.warn(
        f"{path}: truncated: the file ends {extra} bytes into a {unit}; reading the data before.",
        InputWarning,
        stacklevel=3,
    )


def _record_triggers(attrs: dict[str, Any], rising: int, falling: int) -> None:
    if rising or falling:
        attrs["triggers_rising"] = attrs.get("triggers_rising", 0) + rising
        attrs["triggers_falling"] = attrs.get("triggers_falling", 0) + falling


def _iter_dat(path: Path, header: CameraHeader) -> Iterator[EventBlock]:
    unwrap = TimeUnwrapper(1 << 32)
    for words in _read_words(path, header.data_offset, "<u8"):
        pairs = words.view("<u4").reshape(-1, 2)
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
    rising = falling = 0
    for words in _read_words(path, header.data_offset, "<u4"):
        kind = words >> 28
        is_high = kind == 8
        highs = np.concatenate([last_high, unwrap(words[is_high] & 0x0FFFFFFF)])
        last_high = highs[-1:]
        trigger_value = words[kind == 0xA] & 1  # EXT_TRIGGER: the new level, bit 0
        rising += int(trigger_value.sum())
        falling += int(trigger_value.size - trigger_value.sum())
        cd = kind <= 1
        w = words[cd]
        high = highs[np.cumsum(is_high)[cd]]
        yield EventBlock(
            x=((w >> 11) & 0x7FF).astype(np.int16),
            y=(w & 0x7FF).astype(np.int16),
            t=(high << 6) | ((w >> 22) & 0x3F).astype(np.int64),
            p=kind[cd].astype(np.uint8),
        )
    _record_triggers(header.attrs, rising, falling)


# Indices into the EVT 3.0 decoder's state, carried from block to block.
_Y, _BASE_X, _POL, _LOW, _HIGH, _LOOPS, _TIMED, _HIGH_SINCE_LOW = range(8)
_IMPLICIT, _RISING, _FALLING, _UNTIMED = range(8, 12)
_STATE_SIZE = 12


@numba.njit(cache=True, nogil=True)
def _decode_evt3(words, state, fill, x, y, t, p):  # pragma: no cover - compiled
    """Run the EVT 3.0 state machine over ``words``; count events, and store them if ``fill``.

    ``state`` (see the ``_Y`` ... indices) holds the address, the 24-bit time split in low,
    high and its wraps (in µs), whether a time is known yet, and counters. Returns the number
    of events.
    """
    st = state.copy()
    n = 0
    for i in range(words.size):
        w = np.int64(words[i])
        kind = w >> 12
        if kind == 0x0:
            st[_Y] = w & 0x7FF
        elif kind == 0x2 or kind == 0x4 or kind == 0x5:
            if kind == 0x2:
                bits, width, base, pol = np.int64(1), 1, w & 0x7FF, (w >> 11) & 1
            else:
                width = 12 if kind == 0x4 else 8
                bits, base, pol = w & ((1 << width) - 1), st[_BASE_X], st[_POL]
                st[_BASE_X] += width
            if not st[_TIMED]:  # before the first TIME_HIGH, TIME_LOW pair: time unknown
                for b in range(width):
                    st[_UNTIMED] += (bits >> b) & 1
                continue
            now = st[_LOOPS] + (st[_HIGH] << 12) + st[_LOW]
            for b in range(width):
                if (bits >> b) & 1:
                    if fill:
                        x[n], y[n], t[n], p[n] = base + b, st[_Y], now, pol
                    n += 1
        elif kind == 0x3:
            st[_BASE_X] = w & 0x7FF
            st[_POL] = (w >> 11) & 1
        elif kind == 0x6:
            low = w & 0xFFF
            if st[_TIMED] and not st[_HIGH_SINCE_LOW] and st[_LOW] - low > 2048:
                # TIME_LOW wrapped with no TIME_HIGH to say so: a writer that skips them.
                st[_IMPLICIT] += 1
                st[_HIGH] += 1
                if st[_HIGH] == 4096:
                    st[_HIGH] = 0
                    st[_LOOPS] += 1 << 24
            st[_LOW] = low
            st[_TIMED] = st[_TIMED] or st[_HIGH_SINCE_LOW]
            st[_HIGH_SINCE_LOW] = 0
        elif kind == 0x8:
            high = w & 0xFFF
            if st[_HIGH] - high > 2048:  # back by over half the period: the counter wrapped
                st[_LOOPS] += 1 << 24
            st[_HIGH] = high
            st[_HIGH_SINCE_LOW] = 1
        elif kind == 0xA and st[_TIMED]:  # EXT_TRIGGER: the new level in bit 0
            if w & 1:
                st[_RISING] += 1
            else:
                st[_FALLING] += 1
    if fill:
        state[:] = st
    return n


_EVT3_DTYPES = (np.int16, np.int16, np.int64, np.uint8)


class Evt3Decoder:
    """An EVT 3.0 stream decoded a block at a time (timestamps in µs, unwrapped).

    Events before the stream's first TIME_HIGH and TIME_LOW have no known time and are left
    out (a stream joined midway, as event-camera drivers publish it). A TIME_LOW that wraps
    with no TIME_HIGH word in between advances the time by 4096 µs, as writers that skip the
    TIME_HIGH updates mean; conformant streams never do this, and :meth:`finish` warns when it
    happened.
    """

    def __init__(self, source: str) -> None:
        self.source = source
        self.state = np.zeros(_STATE_SIZE, dtype=np.int64)
        self.state[_HIGH] = -1  # no TIME_HIGH seen: the first one cannot look like a wrap

    def decode(self, words: np.ndarray) -> EventBlock:
        """The events of the next ``words`` (uint16) of the stream."""
        n = _decode_evt3(words, self.state, False, *(np.empty(0, d) for d in _EVT3_DTYPES))
        out = [np.empty(n, dtype=d) for d in _EVT3_DTYPES]
        _decode_evt3(words, self.state, True, *out)
        return EventBlock(*out)

    def finish(self, attrs: dict[str, Any]) -> None:
        """Record trigger counts in ``attrs``; warn about TIME_HIGH words the writer skipped."""
        _record_triggers(attrs, int(self.state[_RISING]), int(self.state[_FALLING]))
        if self.state[_IMPLICIT]:
            warnings.warn(
                f"{self.source}: a non-conformant EVT 3.0 stream: TIME_LOW wrapped "
                f"{int(self.state[_IMPLICIT])} times with no TIME_HIGH word; read as its writer "
                "meant (4096 us per wrap).",
                InputWarning,
                stacklevel=3,
            )
