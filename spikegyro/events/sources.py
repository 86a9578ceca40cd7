"""Live event sources: event batches as a camera or the DV software sends them.

A source is named by a URL:

- ``dv://HOST:PORT``: the DV software's network output (or any AEDAT 4 network server, such as
  ``dv_processing.io.NetworkWriter``) over TCP;
- ``dv:///path/to/socket``: the same over a UNIX socket;
- ``camera://`` (the first connected iniVation camera) or ``camera://NAME`` (a named one, as
  ``dv_processing.io.camera.discover()`` lists them), over USB through ``dv-processing``
  (extra ``spikegyro[live]``).

The AEDAT 4 network stream is read here with NumPy: a size-prefixed ``IOHeader`` flatbuffer
(compression, and an XML description of the stream: type, ``sizeX``, ``sizeY``) and then
packets of ``int32`` stream id, ``int32`` size and a size-prefixed flatbuffer; an event packet
(``EVTS``) is a vector of 16-byte events (``int64`` t µs, ``int16`` x, y, ``bool`` polarity).
Reading the bytes here, rather than through ``dv-processing``'s reader, is what lets a packet
cut short by the end of the stream be reported (that reader drops it without a word); the
tests check this reader against ``dv-processing``'s server. Compressed streams are refused:
set the output's compression to none (also the lowest latency).

A camera's events and IMU samples (gyro in deg/s, in its IMU's axes; returned in rad/s) come
through ``dv-processing``'s camera API, polled.
"""

from __future__ import annotations

import re
import socket
import struct
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import ImuBlock, optional_import
from spikegyro.events.core import EventArray

EXTRA = "live"
SCHEMES = ("dv", "camera")
URL_HELP = "dv://HOST:PORT, dv:///path/to/socket, camera:// or camera://NAME"
_EVENT = np.dtype({"names": ["t", "x", "y", "p"], "formats": ["<i8", "<i2", "<i2", "u1"],
                   "offsets": [0, 8, 10, 12], "itemsize": 16})  # fmt: skip
_CAMERA_POLL_S = 0.0005


@dataclass(frozen=True)
class SourceUrl:
    """A parsed source URL: ``scheme`` ``dv`` (``host`` and ``port``, or ``path``) or
    ``camera`` (``name``, empty for the first camera)."""

    text: str
    scheme: str
    host: str = ""
    port: int = 0
    path: str = ""
    name: str = ""


def is_live(source: str) -> bool:
    """Whether ``source`` names a live source (a URL) rather than a file."""
    return re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", str(source)) is not None


def parse_url(text: str) -> SourceUrl:
    """Check a source URL without connecting; raises :class:`InputError` naming what is wrong."""
    scheme, _, rest = text.partition("://")
    if scheme == "camera":
        return SourceUrl(text, "camera", name=rest)
    if scheme != "dv":
        raise InputError(f"{text}: unknown source '{scheme}://'; use {URL_HELP}, or a file.")
    if rest.startswith("/"):
        return SourceUrl(text, "dv", path=rest)
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(
            f"{text}: give the DV output as dv://HOST:PORT (e.g. dv://127.0.0.1:7777)."
        )
    return SourceUrl(text, "dv", host=host.strip("[]"), port=int(port))


class LiveSource:
    """An open source: ``name``, ``sensor`` (width, height) px and ``has_imu``; :meth:`batches`
    yields :class:`EventArray` and :class:`ImuBlock` items as they arrive, until the stream
    ends; ``truncated`` is then the bytes of a packet that the end cut short (0: none)."""

    name: str
    sensor: tuple[int, int]
    has_imu: bool = False
    truncated: int = 0

    def batches(self) -> Iterator[EventArray | ImuBlock]:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


def open_source(text: str, timeout_s: float = 5.0) -> LiveSource:
    """Connect to the source ``text`` names (see the module); one :class:`InputError` line
    when it cannot be opened."""
    url = parse_url(text)
    if url.scheme == "camera":
        return CameraSource(url)
    try:
        if url.path:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(timeout_s)
            sock.connect(url.path)
        else:
            sock = socket.create_connection((url.host, url.port), timeout=timeout_s)
    except OSError as exc:
        raise InputError(
            f"{text}: cannot connect ({exc.strerror or exc}); is the DV network output running "
            "there?"
        ) from None
    sock.settimeout(None)  # blocking reads: each packet is handled the moment it arrives
    try:
        return DvNetworkSource(sock, text)
    except BaseException:
        sock.close()
        raise


def _recv_exact(sock: socket.socket, size: int) -> tuple[bytes, bool]:
    """``size`` bytes, or fewer when the stream ends first (then False)."""
    view, got = bytearray(size), 0
    while got < size:
        n = sock.recv_into(memoryview(view)[got:], size - got)
        if n == 0:
            return bytes(view[:got]), False
        got += n
    return bytes(view), True


def _table(buf: bytes, start: int) -> tuple[int, int, int]:
    """(table position, vtable position, vtable size) of a flatbuffer's root table."""
    table = start + struct.unpack_from("<I", buf, start)[0]
    vtable = table - struct.unpack_from("<i", buf, table)[0]
    return table, vtable, struct.unpack_from("<H", buf, vtable)[0]


def _field(buf: bytes, start: int, index: int) -> int | None:
    """Position of the root table's field ``index``, or None where it is absent."""
    table, vtable, size = _table(buf, start)
    if 4 + 2 * index >= size:
        return None
    offset = struct.unpack_from("<H", buf, vtable + 4 + 2 * index)[0]
    return table + offset if offset else None


def _vector(buf: bytes, at: int) -> tuple[int, int]:
    """(position of the first element, length) of the vector a field at ``at`` points to."""
    vec = at + struct.unpack_from("<I", buf, at)[0]
    return vec + 4, struct.unpack_from("<I", buf, vec)[0]


class DvNetworkSource(LiveSource):
    """An AEDAT 4 network stream of events (see the module)."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        self.sock, self.name = sock, name
        head, whole = _recv_exact(sock, 4)
        body, whole = _recv_exact(sock, struct.unpack("<i", head)[0]) if whole else (b"", False)
        if not whole:
            raise InputError(f"{name}: the stream ended before its header; is it a DV output?")
        try:
            self.stream_id, self.sensor = _event_stream(body, name)
        except (struct.error, ET.ParseError, ValueError, KeyError):
            raise InputError(
                f"{name}: not an AEDAT 4 network stream (unreadable header)."
            ) from None

    def batches(self) -> Iterator[EventArray]:
        width, height = self.sensor
        while True:
            head, whole = _recv_exact(self.sock, 8)
            if not whole:
                self.truncated = len(head)
                return
            stream_id, size = struct.unpack("<ii", head)
            body, whole = _recv_exact(self.sock, size)
            if not whole:
                self.truncated = len(head) + len(body)
                return
            if stream_id != self.stream_id:
                continue
            start, count = _vector(body, _field(body, 4, 0))
            ev = np.frombuffer(body, _EVENT, count, start)
            yield EventArray.from_arrays(ev["x"], ev["y"], ev["t"], ev["p"], width, height,
                                         source=self.name)  # fmt: skip

    def close(self) -> None:
        self.sock.close()


def _event_stream(header: bytes, name: str) -> tuple[int, tuple[int, int]]:
    """The event stream's id and sensor size from an ``IOHeader`` (size prefix removed)."""
    compression = _field(header, 0, 0)
    if compression is not None and struct.unpack_from("<i", header, compression)[0] != 0:
        raise InputError(
            f"{name}: the stream is compressed; set the DV network output's compression to "
            "'none' (it also gives the lowest latency)."
        )
    start, length = _vector(header, _field(header, 0, 2))
    info = ET.fromstring(header[start : start + length].decode())
    for node in info.iter("node"):
        attrs = {a.get("key"): a.text for a in node.iter("attr")}
        if node.get("path", "").count("/") == 3 and attrs.get("typeIdentifier") == "EVTS":
            return int(node.get("name")), (int(attrs["sizeX"]), int(attrs["sizeY"]))
    raise InputError(f"{name}: the stream carries no events; send the camera's event output.")


class CameraSource(LiveSource):
    """An iniVation camera over USB, through ``dv-processing``."""

    def __init__(self, url: SourceUrl) -> None:
        dv = optional_import("dv_processing", EXTRA, url.text)
        try:
            self.camera = dv.io.camera.open(url.name) if url.name else dv.io.camera.open()
        except Exception as exc:  # dv-processing raises RuntimeError for a missing camera
            found = ", ".join(dv.io.camera.discover()) or "none connected"
            raise InputError(
                f"{url.text}: cannot open the camera ({' '.join(str(exc).split())[:120]}); "
                f"cameras found: {found}."
            ) from None
        self.name = f"{url.text} ({self.camera.getCameraName()})"
        self.sensor = tuple(int(v) for v in self.camera.getEventResolution())
        self.has_imu = bool(self.camera.isImuStreamAvailable())

    def batches(self) -> Iterator[EventArray | ImuBlock]:
        width, height = self.sensor
        while self.camera.isRunning():
            events = self.camera.getNextEventBatch()
            imu = self.camera.getNextImuBatch() if self.has_imu else None
            if events is not None and events.size():
                ev = events.numpy()
                yield EventArray.from_arrays(ev["x"], ev["y"], ev["timestamp"], ev["polarity"],
                                             width, height, source=self.name)  # fmt: skip
            if imu:
                yield _imu_block(imu)
            if events is None and not imu:
                time.sleep(_CAMERA_POLL_S)

    def close(self) -> None:
        self.camera = None


def _imu_block(samples: Any) -> ImuBlock:
    """dv-processing IMU samples (gyro deg/s) as an :class:`ImuBlock` (rad/s)."""
    t = np.array([s.timestamp for s in samples], dtype=np.int64)
    gyro = np.array([(s.gyroscopeX, s.gyroscopeY, s.gyroscopeZ) for s in samples], np.float64)
    return ImuBlock(t=t, omega=np.radians(gyro))
