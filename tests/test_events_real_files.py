"""Camera files as cameras and drivers write them.

The real files in ``../shared/real/formats`` are read without any size flag and checked against
the counts their source projects' own tests give (listed in that folder's README). Files that
independent writers make here check the rest: EVT 3.0 written by expelliarmus (which skips
TIME_HIGH words), ``event_camera_msgs/EventPacket`` bags written by ``rosbags`` (ROS 1, ROS 2
sqlite3 and mcap) with libcaer and mono payloads encoded from their layouts, Prophesee headers
that name their sensor in each way Metavision does.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from format_helpers import REAL, assert_events, cli_error, cli_run, needs_real

from spikegyro.errors import InputWarning
from spikegyro.events import EventArray, GyroTrace, Recording, write_recording
from spikegyro.events.event_packet import EVENT_PACKET
from spikegyro.events.io import detect_format, iter_event_chunks, read_gyro_if_any, read_recording


def read_quietly(path: Path) -> Recording:
    """Read ``path``, asserting that it raises no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        return read_recording(path)


# --- Prophesee files -----------------------------------------------------------------------------

# file, sensor (px), events, duration (µs), where the size comes from: facts from the README
PROPHESEE = [
    ("gen3_evt2.raw", (640, 480), 539_481, 50_000, "plugin_name hal_plugin_gen3_fx3"),
    ("gen41_evt3.raw", (1280, 720), 219_596, 8_801, "plugin_name hal_plugin_gen41_evk3"),
]


@needs_real
@pytest.mark.parametrize(("name", "sensor", "count", "duration", "size_from"), PROPHESEE)
def test_prophesee_raw_real(name, sensor, count, duration, size_from):
    rec = read_quietly(REAL / name)
    assert rec.events.sensor_size == sensor
    assert len(rec.events) == count
    assert rec.events.duration_us == duration  # 8.8 ms by TIME_HIGH + TIME_LOW, not 4 ms wraps
    assert rec.attrs["sensor_size_from"].startswith(size_from)
    chunks = list(iter_event_chunks(REAL / name, chunk_events=50_000))
    assert sum(len(c) for c in chunks) == count


@needs_real
def test_dat_without_size_takes_the_smallest_sensor_that_holds_it():
    with pytest.warns(InputWarning, match=r"assuming 304 x 240 px \(ATIS"):
        rec = read_recording(REAL / "atis_ncars.dat")
    assert len(rec.events) == 2009
    assert 99_000 < rec.events.duration_us <= 100_000
    # The user's size wins, with no pass over the data and no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        assert read_recording(REAL / "atis_ncars.dat", sensor=(640, 480)).events.width == 640


def evt2_file(path: Path, header: str, xs, ys) -> Path:
    words = [(8 << 28) | 1]  # TIME_HIGH 1: t = 64 µs on
    words += [(1 << 28) | (int(x) << 11) | int(y) for x, y in zip(xs, ys, strict=True)]
    path.write_bytes(header.encode() + np.array(words, dtype="<u4").tobytes())
    return path


@pytest.mark.parametrize(
    ("lines", "sensor"),
    [
        ("% format EVT2;height=240;width=304\n", (304, 240)),
        ("% geometry 320x320\n", (320, 320)),
        ("% Width 640\n% Height 480\n", (640, 480)),
        ("% plugin_name hal_plugin_gen31_evk3\n", (640, 480)),
        ("% sensor_name IMX636\n", (1280, 720)),
        ("% sensor_generation 320.0\n", (320, 320)),
        ("% system_ID 64\n", (320, 320)),
        ("% system_ID 41\n", (640, 480)),
    ],
)
def test_raw_header_names_the_sensor(tmp_path, lines, sensor):
    path = evt2_file(tmp_path / "cam.raw", "% evt 2.0\n" + lines + "% end\n", [5, 9], [7, 3])
    rec = read_quietly(path)
    assert rec.events.sensor_size == sensor
    assert_events(rec.events, [5, 9], [7, 3], [64, 64], [1, 1])


def test_raw_naming_nothing_is_guessed_with_a_warning(tmp_path, monkeypatch, capsys):
    path = evt2_file(tmp_path / "cam.raw", "% evt 2.0\n% end\n", [5, 310], [7, 300])
    with pytest.warns(InputWarning, match=r"assuming 320 x 320 px \(GenX320"):
        assert read_recording(path).events.sensor_size == (320, 320)
    big = evt2_file(tmp_path / "big.raw", "% evt 2.0\n% end\n", [1500], [7])
    with pytest.warns(InputWarning, match="assuming 1501 x 8 px"):
        assert read_recording(big).events.sensor_size == (1501, 8)
    out, err = cli_run(monkeypatch, capsys, "info", str(path))
    assert "320 x 320" in out and err.count("\n") == 1 and err.startswith("warning: ")


# --- EVT 3.0 that skips TIME_HIGH words, as expelliarmus writes it -----------------------------


def test_evt3_written_by_expelliarmus(tmp_path):
    expelliarmus = pytest.importorskip("expelliarmus")
    rng = np.random.default_rng(11)
    n = 20_000
    events = np.zeros(n, dtype=[("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
    events["t"] = np.sort(rng.integers(0, 98_600, n))
    events["t"][[0, -1]] = 0, 98_600
    events["x"], events["y"] = rng.integers(0, 1280, n), rng.integers(0, 720, n)
    events["p"] = rng.integers(0, 2, n)
    path = tmp_path / "expelliarmus.raw"
    expelliarmus.Wizard(encoding="evt3").save(path, events)
    with pytest.warns(InputWarning, match="non-conformant EVT 3.0.*TIME_LOW wrapped 24 times"):
        rec = read_recording(path)
    assert rec.events.sensor_size == (1280, 720)  # the writer's header names a Gen4.1 EVK3
    assert rec.events.duration_us == 98_600
    assert_events(rec.events, events["x"], events["y"], events["t"], events["p"])


# --- ROS bags of event_camera_msgs/EventPacket -----------------------------------------------

ROS_BAGS = ["ros1_evt3_events_1.bag", "ros2_evt3_events_1", "ros2_evt3_events_1/test_events_1.db3"]


@needs_real
@pytest.mark.parametrize("name", ROS_BAGS)
def test_event_packet_bags_real(name):
    pytest.importorskip("rosbags")
    assert detect_format(REAL / name) == "rosbag"
    rec = read_quietly(REAL / name)
    ev = rec.events
    assert ev.sensor_size == (640, 480)
    # event_camera_py's tests: 218,291 OFF + 125,183 ON CD events, and 2,078 trigger events at
    # level 0 (all of its decoded times, triggers' included, sum to what it expects only if
    # 2,079 more are at level 1).
    assert (int((ev.p == 0).sum()), int((ev.p == 1).sum())) == (218_291, 125_183)
    assert (rec.attrs["triggers_falling"], rec.attrs["triggers_rising"]) == (2078, 2079)
    assert rec.attrs["events_encoding"] == "evt3"
    assert ev.t[0] == 7_139_845  # its first event time (sensor clock, µs)
    assert 2_070_000 < ev.duration_us < 2_100_000
    assert rec.gyro is None and read_gyro_if_any(REAL / name) is None  # a bag without Imu


def copy_bag_to_mcap(src: Path, dst: Path) -> list:
    """Deserialize every message of ``src`` and write them again into an mcap ROS 2 bag."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer

    from spikegyro.events.rosbag import typestore

    store = typestore(ros2=True)
    messages = []
    with AnyReader([src], default_typestore=store) as reader:
        for conn, stamp, raw in reader.messages():
            messages.append(
                (conn.topic, conn.msgtype, stamp, reader.deserialize(raw, conn.msgtype))
            )
    with Writer(dst, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msgtype, stamp, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], stamp, store.serialize_cdr(msg, msgtype))
    return messages


@needs_real
def test_event_packet_mcap_written_from_the_real_bag(tmp_path):
    pytest.importorskip("rosbags")
    copy_bag_to_mcap(REAL / "ros2_evt3_events_1", tmp_path / "bag")
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    assert mcap.read_bytes()[:8] == b"\x89MCAP0\r\n"
    want = read_quietly(REAL / "ros1_evt3_events_1.bag").events
    for path in (tmp_path / "bag", mcap):  # the bag folder, and its .mcap file alone
        assert detect_format(path) == "rosbag"
        got = read_quietly(path).events
        assert_events(got, want.x, want.y, want.t, want.p)


def _stamp(types, t_ns: int):
    return types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def write_packet_bag(path: Path, packets, ros2: bool, imu=()) -> None:
    """A bag of EventPacket messages (encoding, time_base ns, payload bytes) and Imu samples."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    from spikegyro.events.rosbag import typestore

    store = typestore(ros2=ros2)
    types = store.types
    serialize = store.serialize_cdr if ros2 else store.serialize_ros1
    with Writer2(path, version=8) if ros2 else Writer1(path) as writer:
        ev = writer.add_connection("/cam/events", EVENT_PACKET, typestore=store)
        imu_conn = writer.add_connection("/cam/imu", "sensor_msgs/msg/Imu", typestore=store)
        header = types["std_msgs/msg/Header"]
        for seq, (encoding, time_base, payload) in enumerate(packets):
            kw = {"seq": seq} if not ros2 else {}
            msg = types["event_camera_msgs/msg/EventPacket"](
                header=header(**kw, stamp=_stamp(types, time_base), frame_id="cam"),
                height=260, width=346, seq=seq, time_base=time_base, encoding=encoding,
                is_bigendian=False, events=np.frombuffer(payload, dtype=np.uint8),
            )  # fmt: skip
            writer.write(ev, int(time_base) + 1, serialize(msg, msg.__msgtype__))
        vec, quat = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
        for seq, (t_ns, w) in enumerate(imu):
            kw = {"seq": seq} if not ros2 else {}
            msg = types["sensor_msgs/msg/Imu"](
                header=header(**kw, stamp=_stamp(types, t_ns), frame_id="imu"),
                orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
                angular_velocity=vec(x=w[0], y=w[1], z=w[2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=np.zeros(9),
            )  # fmt: skip
            writer.write(imu_conn, t_ns, serialize(msg, msg.__msgtype__))


def libcaer_payload(x, y, t_us, p) -> bytes:
    """libcaer polarity records: uint32 (valid bit 0, polarity 1, y 2-16, x 17-31), int32 µs
    (the 31-bit counter, wrapping)."""
    data = (np.asarray(x, np.uint32) << 17) | (np.asarray(y, np.uint32) << 2)
    data |= (np.asarray(p, np.uint32) << 1) | 1
    rec = np.zeros(len(data), dtype=[("d", "<u4"), ("t", "<i4")])
    rec["d"], rec["t"] = data, np.asarray(t_us) % (1 << 31)
    return rec.tobytes()


def mono_payload(x, y, t_ns, p) -> bytes:
    """mono records: uint64 (ns after the time base in bits 0-31, x 32-47, y 48-62, p 63)."""
    words = [int(c) | (int(a) << 32) | (int(b) << 48) | (int(d) << 63)
             for a, b, c, d in zip(x, y, t_ns, p, strict=True)]  # fmt: skip
    return np.array(words, dtype="<u8").tobytes()


@pytest.mark.parametrize("ros2", [False, True])
def test_event_packet_libcaer_and_mono(tmp_path, ros2):
    pytest.importorskip("rosbags")
    rng = np.random.default_rng(12)
    epoch_us = 1_700_000_000_000_000
    # libcaer: the packet's time base plus a 31-bit µs counter that wraps inside packet 2.
    x, y, p = rng.integers(0, 346, 900), rng.integers(0, 260, 900), rng.integers(0, 2, 900)
    counter = np.sort(rng.integers((1 << 31) - 300_000, (1 << 31) + 300_000, 900))
    base_us = epoch_us
    parts = np.array_split(np.arange(900), 3)
    packets = [
        ("libcaer", int(base_us + counter[k[0]] - counter[k[0]] % (1 << 31)) * 1000,
         libcaer_payload(x[k], y[k], counter[k], p[k]))
        for k in parts
    ]  # fmt: skip
    # Two mono packets, times in ns after their base (a base that is not a whole µs).
    t_mono = np.sort(rng.integers(0, 4_000_000, 60))
    mono_base = (epoch_us + 700_000) * 1000 + 321
    for k in np.array_split(np.arange(60), 2):
        packets.append(("mono", mono_base, mono_payload(x[k], y[k], t_mono[k], p[k])))
    imu = [((epoch_us + 1000 * i) * 1000, (0.1, -0.2, 0.3 * i)) for i in range(5)]
    path = tmp_path / ("bag2" if ros2 else "rec.bag")
    write_packet_bag(path, packets, ros2, imu)
    rec = read_quietly(path)
    assert rec.events.sensor_size == (346, 260)
    want_x, want_y, want_p = (np.concatenate([v, v[:60]]) for v in (x, y, p))
    want_t = np.concatenate([base_us + counter, (mono_base + t_mono) // 1000])
    assert_events(rec.events, want_x, want_y, want_t, want_p)
    np.testing.assert_array_equal(rec.gyro.t, [t // 1000 for t, _ in imu])
    np.testing.assert_allclose(rec.gyro.omega[:, 2], [0.3 * i for i in range(5)])


def test_event_packet_unknown_encoding(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rosbags")
    path = tmp_path / "rec.bag"
    write_packet_bag(path, [("evt2", 10**18, b"\0" * 16)], ros2=False)
    err = cli_error(monkeypatch, capsys, "info", str(path))
    assert "evt2" in err and "evt3, libcaer, libcaer_cmp, mono" in err


@needs_real
@pytest.mark.parametrize("name", ["", "test_events_2_0.mcap"])
def test_libcaer_cmp_bag_real(name):
    pytest.importorskip("rosbags")
    # The folder's metadata.yaml names no storage plugin: its .mcap is opened by extension.
    path = REAL / "ros2_davis346_libcaer_cmp" / name
    assert detect_format(path) == "rosbag"
    ev = read_quietly(path).events
    assert ev.sensor_size == (346, 260)
    # event_camera_py's tests/test_2.py: 360,223 OFF + 211,043 ON events, the first sensor time
    # 1744227144732712 µs, and the times, counted from it, sum to 335,555,680,277 µs.
    assert (int((ev.p == 0).sum()), int((ev.p == 1).sum())) == (360_223, 211_043)
    assert ev.t[0] == 1_744_227_144_732_712
    assert int((ev.t - ev.t[0]).sum()) == 335_555_680_277


def cmp_words(events, start=None) -> bytes:
    """libcaer_cmp words for (x, y, t_us, p) events of one packet, from the layout: TIME_HIGH,
    TIME_LOW, ADDR_X when they change, then ADDR_Y; runs of ``start`` (x, base y, polarity)
    as VECT_BASE_Y and VECT_8 words instead."""
    words, state = [], {}
    for x, y, t, p in events:
        for code, value in ((0, t >> 12), (1, t & 0xFFF), (2, x)):
            if state.get(code) != value:
                words.append((code << 12) | value)
                state[code] = value
        words.append((3 << 12) | (p << 11) | y)
    if start is not None:  # two VECT_8 words: y = base + 0..7, then base + 8 + 0..7
        x, base, p, bits = start
        words += [(2 << 12) | x, (4 << 12) | (p << 11) | base]
        words += [(5 << 12) | (b & 0xFF) for b in bits]
    return np.array(words, dtype="<u2").tobytes()


def test_libcaer_cmp_layout(tmp_path):
    pytest.importorskip("rosbags")
    base_ns = 1_700_000_000_123_456_789  # not a whole µs: the decoder floors it
    base_us = base_ns // 1000
    one = [(3, 4, 5, 1), (3, 9, 5000, 0), (345, 259, 70_000, 1), (400, 10, 70_001, 1)]
    packets = [
        ("libcaer_cmp", base_ns, cmp_words(one, start=(7, 100, 1, (0b101, 0b10000000)))),
        # continues the vector of packet 1 (base 116 now) at its x, with times from 0 again
        ("libcaer_cmp", base_ns + 10**8, np.array([(5 << 12) | 0b11], "<u2").tobytes()),
    ]
    path = tmp_path / "bag2"
    write_packet_bag(path, packets, ros2=True)
    ev = read_quietly(path).events
    t_last = base_us + 70_001
    want = [
        (3, 4, base_us + 5, 1), (3, 9, base_us + 5000, 0), (345, 259, base_us + 70_000, 1),
        (7, 100, t_last, 1), (7, 102, t_last, 1), (7, 115, t_last, 1),  # x 400: off the sensor
        (7, 116, base_us + 10**5, 1), (7, 117, base_us + 10**5, 1),
    ]  # fmt: skip
    assert_events(ev, *(np.array(c) for c in zip(*want, strict=True)))


# --- every real file through `spikegyro info`, without size flags --------------------------------

INFO = {
    "atis_ncars.dat": "2,009",
    "gen3_evt2.raw": "539,481",
    "gen41_evt3.raw": "219,596",
    "ros1_evt3_events_1.bag": "343,474",
    "ros2_evt3_events_1": "343,474",
    "ros2_davis346_libcaer_cmp": "571,266",
    "dvxplorer_static_imu.aedat4": "111,954",
}


@needs_real
@pytest.mark.parametrize("name", sorted(INFO))
def test_info_reads_every_real_file(monkeypatch, capsys, name):
    if name.startswith("ros"):
        pytest.importorskip("rosbags")
    if name.endswith(".aedat4"):
        pytest.importorskip("aedat")
    out, _ = cli_run(monkeypatch, capsys, "info", str(REAL / name))
    assert "events" in out and INFO[name] in out


# --- convert into an existing folder ---------------------------------------------------------


def test_convert_refuses_a_partial_folder_overwrite(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(13)
    t = np.sort(rng.integers(0, 100_000, 50))
    ev = EventArray.from_arrays(rng.integers(0, 240, 50), rng.integers(0, 180, 50), t,
                                rng.integers(0, 2, 50), 240, 180)  # fmt: skip
    gyro = GyroTrace.from_arrays(np.arange(0, 100_000, 1000), np.zeros((100, 3)))
    src = write_recording(tmp_path / "src.h5", Recording(ev, gyro))
    out = tmp_path / "ecd"
    out.mkdir()
    for name in ("events.txt", "calib.txt", "imu.txt"):
        (out / name).write_text("0 1 2 3\n")
    err = cli_error(monkeypatch, capsys, "convert", str(src), str(out))
    assert "calib.txt" in err and "--force" in err
    assert (out / "events.txt").read_text() == "0 1 2 3\n"  # untouched
    cli_run(monkeypatch, capsys, "convert", str(src), str(out), "--force")
    assert sorted(q.name for q in out.iterdir()) == ["events.txt", "gyro.txt"]
    assert_events(read_recording(out).events, ev.x, ev.y, ev.t, ev.p)
    assert [q.name for q in tmp_path.iterdir() if q.name.startswith(".")] == []
    # The input inside the folder it would replace: refused even with --force.
    err = cli_error(monkeypatch, capsys, "convert", str(out / "events.txt"), str(out), "--force")
    assert "holds the input" in err
