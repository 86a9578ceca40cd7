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
ENCODINGS = ("evt3", "libcaer", "mono")
_LIBCAER = np.dtype([("data", "<u4"), ("t", "<i4")])
_LIBCAER_WRAP_US = 1 << 31


class PacketDecoder:
    """Decodes the successive EventPacket messages of one topic into event blocks."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.evt3 = Evt3Decoder(source)
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
