"""ROS bags (ROS 1 ``.bag``; ROS 2 bag folders and ``.db3`` / ``.mcap`` files) of events and
``sensor_msgs/Imu``.

Read with the pure-Python ``rosbags`` package (extra ``spikegyro[rosbag]``), which needs no ROS
installation. Events come from the first topic (alphabetically) of ``dvs_msgs/EventArray``
(rpg_dvs_ros) or ``event_camera_msgs/EventPacket`` (the ROS event-camera drivers, decoded by
:mod:`~spikegyro.events.event_packet`); both types are registered from their message
definitions. Gyro samples (``angular_velocity``, rad/s, in the IMU message's frame: give
``--imu-to-camera``) come from the first ``sensor_msgs/Imu`` topic. Timestamps: each event's
``ts`` (EventArray) or the packet's time base plus the decoded time (EventPacket), each IMU
message's header stamp, in µs. ROS 1 event arrays are decoded straight from their bytes with
NumPy (13 bytes per event); other messages go through the library's deserializer. Messages are
read in the bag's order; ones out of time order are put back in order. ROS 2 bags are read
with these message types, not the definitions they embed (drivers write IDL that ``rosbags``
cannot parse); a bag folder whose ``metadata.yaml`` names no storage plugin is read from its
``.mcap`` or ``.db3`` files, by extension.
"""

from __future__ import annotations

import heapq
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import CameraHeader, EventBlock, ImuBlock, optional_import
from spikegyro.events.event_packet import DEFINITION, EVENT_PACKET, PacketDecoder

FORMATS = ("rosbag",)
EXTRA = "rosbag"
EVENT_ARRAY = "dvs_msgs/msg/EventArray"
IMU = "sensor_msgs/msg/Imu"
DVS_MSGS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\ntime ts\nbool polarity\n",
    EVENT_ARRAY: "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
    EVENT_PACKET: DEFINITION,
}
EVENT_TYPES = (EVENT_ARRAY, EVENT_PACKET)
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])


def sniff(path: Path, head: bytes) -> str | None:
    """``rosbag`` for a ROS 1 bag, a ROS 2 bag folder (``metadata.yaml``) or a ROS 2 storage
    file (``.mcap``, or ``.db3`` SQLite), else None."""
    if head.startswith((b"#ROSBAG V2", _MCAP_MAGIC)):
        return "rosbag"
    if head.startswith(_SQLITE_MAGIC) and path.suffix.lower() == ".db3":
        return "rosbag"
    if path.is_dir() and (path / "metadata.yaml").exists():
        return "rosbag"
    return None


def _is_ros2(path: Path) -> bool:
    # As rosbags decides: anything but a .bag file is ROS 2.
    return path.suffix != ".bag"


def typestore(ros2: bool = False) -> Any:
    """A ``rosbags`` type store that knows the ``dvs_msgs`` types (ROS 1 Noetic or ROS 2)."""
    typesys = optional_import("rosbags.typesys", EXTRA, "rosbag")
    store = typesys.get_typestore(
        typesys.Stores.ROS2_HUMBLE if ros2 else typesys.Stores.ROS1_NOETIC
    )
    for name, text in DVS_MSGS.items():
        store.register(typesys.get_types_from_msg(text, name))
    return store


def _open(path: Path) -> Any:
    if _is_ros2(path):
        reader = _Ros2Reader(_ros2_paths(path))
    else:
        highlevel = optional_import("rosbags.highlevel", EXTRA, path)
        reader = highlevel.AnyReader([path], default_typestore=typestore())
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError types on bad or unindexed bags
        raise InputError(f"{path}: not a readable ROS bag ({exc}).") from None
    return reader


def _ros2_paths(path: Path) -> list[Path]:
    """The bag folder itself, or its storage files where its ``metadata.yaml`` names no storage
    plugin (as some recorders write it): then each file is opened by its extension."""
    meta = path / "metadata.yaml"
    if not path.is_dir() or not meta.is_file():
        return [path]
    text = meta.read_text(errors="replace")
    if not re.search(r"^\s*storage_identifier:\s*(\"\"|'')?\s*$", text, re.MULTILINE):
        return [path]
    files = [f for f in sorted(path.iterdir()) if f.suffix.lower() in (".mcap", ".db3")]
    if not files:
        raise InputError(f"{path}: a ROS 2 bag folder without .mcap or .db3 files.")
    return files


class _Ros2Reader:
    """ROS 2 storage read with spikegyro's own message types (``rosbags``' reader per folder or
    storage file, messages merged in time order). The definitions that bags embed are not
    parsed: drivers write IDL that ``rosbags`` cannot parse, and only the types of
    :data:`DVS_MSGS` and ``sensor_msgs/Imu`` are read."""

    def __init__(self, paths: list[Path]) -> None:
        rosbag2 = optional_import("rosbags.rosbag2", EXTRA, paths[0])
        self.readers = [rosbag2.Reader(p) for p in paths]
        self.store = typestore(ros2=True)
        self.connections: list[Any] = []

    def open(self) -> None:
        try:
            for reader in self.readers:
                reader.open()
        except Exception:
            self.close()
            raise
        self.connections = [c for r in self.readers for c in r.connections]

    def messages(self, connections: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        wanted = {id(c) for c in connections}
        streams = [
            r.messages(connections=[c for c in r.connections if id(c) in wanted])
            for r in self.readers
            if any(id(c) in wanted for c in r.connections)
        ]
        return heapq.merge(*streams, key=lambda message: message[1])

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.store.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        for reader in self.readers:
            if reader.is_open:
                reader.close()


def _topics(reader: Any) -> tuple[list[Any], list[Any]]:
    conns = sorted(reader.connections, key=lambda c: c.topic)
    ev_topic = next((c.topic for c in conns if c.msgtype in EVENT_TYPES), None)
    imu_topic = next((c.topic for c in conns if c.msgtype == IMU), None)
    return (
        [c for c in conns if c.topic == ev_topic],
        [c for c in conns if c.topic == imu_topic],
    )


@contextmanager
def _reading(path: Path) -> Iterator[Any]:
    """The bag's reader, closed on leaving; a message it cannot parse is one InputError line."""
    reader = _open(path)
    try:
        yield reader
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{path}: a corrupt or truncated ROS bag message ({exc}).") from None
    finally:
        reader.close()


def read_header(path: Path, fmt: str) -> CameraHeader:
    """Sensor size from the first event message; the event and IMU topics as attributes."""
    with _reading(path) as reader:
        ev_conns, imu_conns = _topics(reader)
        attrs: dict[str, Any] = {}
        sensor = None
        if ev_conns:
            attrs["events_topic"] = ev_conns[0].topic
            for conn, _, raw in reader.messages(connections=ev_conns):
                if conn.msgtype == EVENT_ARRAY and not _is_ros2(path):
                    width, height = _ros1_size(raw, path)
                else:
                    msg = reader.deserialize(raw, conn.msgtype)
                    width, height = msg.width, msg.height
                    if conn.msgtype == EVENT_PACKET:
                        attrs["events_encoding"] = str(msg.encoding)
                sensor = (int(width), int(height))
                break
        if imu_conns:
            attrs["imu_topic"] = imu_conns[0].topic
    return CameraHeader(fmt=fmt, sensor=sensor, attrs=attrs)


def _ros1_skip_header(raw: bytes, path: Path) -> int:
    """Offset just after a ROS 1 std_msgs/Header (uint32 seq, time stamp, string frame_id)."""
    if len(raw) < 16:
        raise InputError(f"{path}: a truncated dvs_msgs/EventArray message.")
    (frame_len,) = np.frombuffer(raw, dtype="<u4", count=1, offset=12)
    return 16 + int(frame_len)


def _ros1_size(raw: bytes, path: Path) -> tuple[int, int]:
    off = _ros1_skip_header(raw, path)
    height, width = np.frombuffer(raw, dtype="<u4", count=2, offset=off)
    return int(width), int(height)


def _ros1_events(raw: bytes, path: Path) -> EventBlock:
    off = _ros1_skip_header(raw, path) + 8
    if len(raw) < off + 4:
        raise InputError(f"{path}: a truncated dvs_msgs/EventArray message.")
    (n,) = np.frombuffer(raw, dtype="<u4", count=1, offset=off)
    if len(raw) < off + 4 + int(n) * _ROS1_EVENT.itemsize:
        raise InputError(f"{path}: a truncated dvs_msgs/EventArray message.")
    ev = np.frombuffer(raw, dtype=_ROS1_EVENT, count=int(n), offset=off + 4)
    return EventBlock(
        x=ev["x"].astype(np.int16),
        y=ev["y"].astype(np.int16),
        t=ev["sec"].astype(np.int64) * 1_000_000 + ev["nsec"].astype(np.int64) // 1000,
        p=ev["p"].astype(np.uint8),
    )


def _deserialized_events(msg: Any) -> EventBlock:
    ev = msg.events
    return EventBlock(
        x=np.fromiter((e.x for e in ev), dtype=np.int16, count=len(ev)),
        y=np.fromiter((e.y for e in ev), dtype=np.int16, count=len(ev)),
        t=np.fromiter(
            (e.ts.sec * 1_000_000 + e.ts.nanosec // 1000 for e in ev), dtype=np.int64, count=len(ev)
        ),
        p=np.fromiter((e.polarity for e in ev), dtype=np.uint8, count=len(ev)),
    )


def _event_decoder(path: Path, reader: Any, conn: Any) -> tuple[Any, PacketDecoder | None]:
    """A function from a raw event message to its events, and the packet decoder if any."""
    if conn.msgtype == EVENT_PACKET:
        packets = PacketDecoder(str(path))
        return lambda raw: packets.decode(reader.deserialize(raw, conn.msgtype)), packets
    if _is_ros2(path):
        return lambda raw: _deserialized_events(reader.deserialize(raw, conn.msgtype)), None
    return lambda raw: _ros1_events(raw, path), None


def _imu_block(msgs: list[Any]) -> ImuBlock:
    """The gyro samples of deserialized Imu messages (stamps in µs, ω in rad/s)."""
    t = [m.header.stamp.sec * 1_000_000 + m.header.stamp.nanosec // 1000 for m in msgs]
    w = [(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in msgs]
    return ImuBlock(t=np.array(t, dtype=np.int64), omega=np.array(w, dtype=np.float64))


def iter_blocks(
    path: Path, header: CameraHeader, *, events: bool = True, imu: bool = True
) -> Iterator[EventBlock | ImuBlock]:
    """One block per event message; IMU messages gathered a thousand at a time. Once the bag is
    read, EventPacket trigger counts are added to ``header.attrs``."""
    with _reading(path) as reader:
        ev_conns, imu_conns = _topics(reader)
        wanted = (ev_conns if events else []) + (imu_conns if imu else [])
        if not wanted:  # rosbags reads every topic when given none
            return
        ev_ids = {c.id for c in ev_conns}
        decode, packets = _event_decoder(path, reader, ev_conns[0]) if ev_conns else (None, None)
        imu_msgs: list[Any] = []
        for conn, _, raw in reader.messages(connections=wanted):
            if conn.id in ev_ids:
                yield decode(raw)
                continue
            imu_msgs.append(reader.deserialize(raw, conn.msgtype))
            if len(imu_msgs) >= 1000:
                yield _imu_block(imu_msgs)
                imu_msgs = []
        if imu_msgs:
            yield _imu_block(imu_msgs)
        if packets is not None and events:
            packets.finish(header.attrs)
