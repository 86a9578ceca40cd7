"""Payloads of ``event_camera_msgs/EventPacket``, the message of the ROS event-camera drivers
(``metavision_driver`` for Prophesee cameras, ``libcaer_driver`` for iniVation ones).

The message carries a header, the sensor's ``width`` and ``height``, a ``seq`` number, a
``time_base`` in ns, the ``encoding`` name and the ``events`` as bytes. An event's time is
``time_base`` plus the time decoded from the bytes (both ns; here rounded down to µs):

- ``evt3``: a piece of the camera's EVT 3.0 stream (Prophesee), decoded by
  :class:`~spikegyro.events.prophesee.Evt3Decoder` with its state carried from message to
  message. ``time_base`` is 0, so times are the sensor's clock (a 24-bit µs counter, unwrapped
  from the first message on), not ROS time. External triggers are counted apart.
- ``libcaer``: 8-byte little-endian records of uint32 data (polarity = bit 1, y = bits 2-16,
  x = bits 17-31) and int32 time in µs since the packet's ``time_base``; a time that goes back
  within a packet means the 31-bit counter wrapped.
- ``libcaer_cmp``: the compressed libcaer stream of the ROS 2 ``libcaer_driver``: little-endian
  16-bit words, a 4-bit code in bits 12-15 over 12 bits of data. TIME_HIGH (0) sets bits 12-23
  and TIME_LOW (1) bits 0-11 of the µs since the packet's ``time_base`` (both 0 at each
  packet's start); ADDR_X (2) sets x (bits 0-10); ADDR_Y (3) is one event at that x with y in
  bits 0-10 and polarity in bit 11; VECT_BASE_Y (4) sets a base y and polarity for VECT_8 (5),
  whose bits 0-7 are events at base y + 0..7, after which the base moves up by 8. x, the base
  y and its polarity carry over from packet to packet; other codes carry no events.
- ``mono``: little-endian uint64 records: time in ns since ``time_base`` in bits 0-31, x in
  bits 32-47, y in bits 48-62, polarity in bit 63.

Events outside the message's ``width`` x ``height`` are dropped, as the drivers' own decoders
do.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import EventBlock
from spikegyro.events.prophesee import Evt3Decoder, warn_truncated

EVENT_PACKET = "event_camera_msgs/msg/EventPacket"
DEFINITION = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
    "string encoding\nbool is_bigendian\nuint8[] events\n"
)
"""The message definition (the same in ROS 1 and ROS 2)."""
ENCODINGS = ("evt3", "libcaer", "libcaer_cmp", "mono")
_LIBCAER = np.dtype([("data", "<u4"), ("t", "<i4")])
_LIBCAER_WRAP_US = 1 << 31


class PacketDecoder:
    """Decodes the successive EventPacket messages of one topic into event blocks."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.evt3 = Evt3Decoder(source)
        self.cmp = LibcaerCmpDecoder()
        self.dropped = 0

    def decode(self, msg: Any) -> EventBlock:
        """The events of one message (``msg``: a deserialized EventPacket), t in µs."""
        encoding = str(msg.encoding)
        payload = np.asarray(msg.events, dtype=np.uint8)
        base_us = int(msg.time_base) // 1000  # exact: evt3, libcaer times are whole µs
        if encoding == "evt3":
            block = self.evt3.decode(self._records(payload, 2).view("<u2"))
            block = EventBlock(block.x, block.y, block.t + base_us, block.p)
        elif encoding == "libcaer":
            block = _libcaer(self._records(payload, 8).view(_LIBCAER), base_us)
        elif encoding == "libcaer_cmp":
            block = self.cmp.decode(self._records(payload, 2).view("<u2"), base_us)
        elif encoding == "mono":
            block = _mono(self._records(payload, 8).view("<u8"), int(msg.time_base))
        else:
            raise InputError(
                f"{self.source}: EventPacket encoding '{encoding}' is not read; "
                f"{', '.join(ENCODINGS)} are (re-record with one of them)."
            )
        return self._inside(block, int(msg.width), int(msg.height))

    def _records(self, payload: np.ndarray, size: int) -> np.ndarray:
        extra = payload.size % size
        if extra:
            warn_truncated(self.source, extra, f"{size}-byte EventPacket record")
        return payload[: payload.size - extra]

    def _inside(self, block: EventBlock, width: int, height: int) -> EventBlock:
        keep = (block.x >= 0) & (block.x < width) & (block.y < height)
        if keep.all():
            return block
        self.dropped += int((~keep).sum())
        return EventBlock(block.x[keep], block.y[keep], block.t[keep], block.p[keep])

    def finish(self, attrs: dict[str, Any]) -> None:
        """Record trigger counts and events dropped outside the sensor in ``attrs``."""
        self.evt3.finish(attrs)
        if self.dropped:
            attrs["events_outside_sensor"] = self.dropped


_TIME_HIGH, _TIME_LOW, _ADDR_X, _ADDR_Y, _VECT_BASE_Y, _VECT_8 = range(6)


def _last_value(mask: np.ndarray, values: np.ndarray, before: int) -> np.ndarray:
    """At each word, the value of the last word where ``mask`` holds (inclusive), or ``before``
    where none did yet."""
    index = np.maximum.accumulate(np.where(mask, np.arange(mask.size), -1))
    return np.where(index >= 0, values[np.maximum(index, 0)], before)


class LibcaerCmpDecoder:
    """``libcaer_cmp`` payloads (see the module), with x and the vector base carried over."""

    def __init__(self) -> None:
        self.x = self.base_y = self.polarity = 0

    def decode(self, words: np.ndarray, base_us: int) -> EventBlock:
        """The events of one packet's 16-bit words; t = ``base_us`` + the packet's µs."""
        code, data = (words >> 12).astype(np.int64), (words & 0xFFF).astype(np.int64)
        time_us = _last_value(code == _TIME_HIGH, data << 12, 0)
        time_us += _last_value(code == _TIME_LOW, data, 0)
        x = _last_value(code == _ADDR_X, data & 0x7FF, self.x)
        # VECT_8 n after its base: y from base + 8 * (VECT_8 words since that base)
        is_base, is_vect = code == _VECT_BASE_Y, code == _VECT_8
        vects = np.cumsum(is_vect) - is_vect
        since = vects - _last_value(is_base, vects, 0)
        base = _last_value(is_base, data & 0x7FF, self.base_y) + 8 * since
        vect_p = _last_value(is_base, data >> 11, self.polarity)
        single = np.flatnonzero(code == _ADDR_Y)
        vect = np.flatnonzero(is_vect)
        row, bit = np.nonzero((data[vect, None] >> np.arange(8)) & 1)
        word = vect[row]
        order = np.argsort(np.concatenate([single, word]), kind="stable")
        self._carry(code, x, base, vect_p, is_vect)
        return EventBlock(
            x=np.concatenate([x[single], x[word]])[order].astype(np.int16),
            y=np.concatenate([data[single] & 0x7FF, base[word] + bit])[order].astype(np.int16),
            t=base_us + np.concatenate([time_us[single], time_us[word]])[order],
            p=np.concatenate([data[single] >> 11, vect_p[word]])[order].astype(np.uint8),
        )

    def _carry(
        self,
        code: np.ndarray,
        x: np.ndarray,
        base: np.ndarray,
        polarity: np.ndarray,
        is_vect: np.ndarray,
    ) -> None:
        """Keep the packet's last x, vector base and polarity for the next one."""
        if code.size:
            self.x, self.polarity = int(x[-1]), int(polarity[-1])
            self.base_y = int(base[-1]) + 8 * int(is_vect[-1])


def _libcaer(records: np.ndarray, base_us: int) -> EventBlock:
    data = records["data"]
    t = records["t"].astype(np.int64)
    wraps = np.concatenate([[0], np.cumsum(t[1:] < t[:-1])])
    return EventBlock(
        x=((data >> 17) & 0x7FFF).astype(np.int16),
        y=((data >> 2) & 0x7FFF).astype(np.int16),
        t=base_us + t + wraps * _LIBCAER_WRAP_US,
        p=((data >> 1) & 1).astype(np.uint8),
    )


def _mono(records: np.ndarray, time_base_ns: int) -> EventBlock:
    return EventBlock(
        x=((records >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.int16),
        y=((records >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.int16),
        t=(time_base_ns + (records & np.uint64(0xFFFFFFFF)).astype(np.int64)) // 1000,
        p=(records >> np.uint64(63)).astype(np.uint8),
    )
