"""AEDAT 4 and ROS bags written by their libraries' own writers, read back exactly; ``convert``.

The AEDAT 4 files are written with ``faery``'s encoder and read with the ``aedat`` decoder; the
bags with ``rosbags``' writer and serializer, read by our NumPy decoder of the ROS 1 bytes. Tests
needing an optional package skip when it is absent; ``convert`` between our own formats and the
missing-extra error run always.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from format_helpers import assert_events, cli_error

from spikegyro.errors import InputError
from spikegyro.events import EventArray, GyroTrace, Recording, write_recording
from spikegyro.events.convert import convert
from spikegyro.events.imu import imu_rotation
from spikegyro.events.io import detect_format, iter_event_chunks, read_gyro, read_recording

BIG_T0 = (1 << 32) + 777


def random_events(n: int, width: int, height: int, t0: int, span: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(t0, t0 + span, n))
    return rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n)


# --- AEDAT 4 -------------------------------------------------------------------------------------


def write_aedat4(path, packets, gyro=None, sensor=(346, 260)) -> None:
    faery = pytest.importorskip("faery")
    pytest.importorskip("aedat")
    from spikegyro.events.convert import _aedat4_description, _aedat4_imus

    ext = faery.extension.aedat
    with ext.Encoder(str(path), _aedat4_description(ext, sensor, gyro), ext.LZ4_DEFAULT) as enc:
        for x, y, t, p in packets:
            ev = np.zeros(len(t), dtype=faery.EVENTS_DTYPE)
            ev["t"], ev["x"], ev["y"], ev["on"] = t, x, y, p.astype(bool)
            enc.write(0, ev)
        if gyro is not None:
            enc.write(1, _aedat4_imus(gyro))


def test_aedat4_round_trip(tmp_path, monkeypatch, capsys):
    x, y, t, p = random_events(3000, 346, 260, BIG_T0, 400_000, seed=5)
    gyro = GyroTrace.from_arrays(BIG_T0 + np.arange(0, 400_000, 1000), np.zeros((400, 3)) + 0.5)
    path = tmp_path / "rec.aedat4"
    # faery's encoder only writes a stream's events in time order; the IMU packets come after
    # all the event packets, so they are out of order across streams.
    parts = (slice(0, 1000), slice(1000, 2500), slice(2500, None))
    write_aedat4(path, [(x[s], y[s], t[s], p[s]) for s in parts], gyro=gyro)
    assert detect_format(path) == "aedat4"
    rec = read_recording(path, imu_to_camera=imu_rotation("y,-x,z"))
    assert rec.events.sensor_size == (346, 260)
    assert_events(rec.events, x, y, t, p)
    np.testing.assert_array_equal(rec.gyro.t, gyro.t)
    np.testing.assert_allclose(rec.gyro.omega, np.tile([0.5, -0.5, 0.5], (400, 1)), rtol=1e-6)
    chunks = list(iter_event_chunks(path, chunk_events=500))
    assert max(len(c) for c in chunks) <= 500
    assert_events(EventArray.concatenate(chunks), x, y, t, p)
    empty = tmp_path / "empty.aedat4"
    write_aedat4(empty, [])
    assert len(read_recording(empty).events) == 0
    bad = tmp_path / "bad.aedat4"
    bad.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert "bad.aedat4" in cli_error(monkeypatch, capsys, "info", str(bad))


def test_missing_extra_is_named(tmp_path, monkeypatch):
    path = tmp_path / "rec.aedat4"
    path.write_bytes(b"#!AER-DAT4.0\r\n" + b"\0" * 64)
    monkeypatch.setitem(sys.modules, "aedat", None)  # import aedat now raises ImportError
    with pytest.raises(InputError, match=r"pip install 'spikegyro\[aedat4\]'"):
        read_recording(path)


# --- ROS bags ------------------------------------------------------------------------------------


def write_bag(path, messages, imu=()) -> None:
    """``messages``: (x, y, t_us, p) arrays, one dvs_msgs/EventArray each, in this order."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer

    from spikegyro.events.rosbag import typestore

    store = typestore()
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]

    def stamp(t_us: int):
        return Time(sec=int(t_us) // 1_000_000, nanosec=int(t_us) % 1_000_000 * 1000)

    with Writer(path) as writer:
        ev_conn = writer.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        imu_conn = writer.add_connection("/dvs/imu", "sensor_msgs/msg/Imu", typestore=store)
        for seq, (x, y, t, p) in enumerate(messages):
            events = [
                types["dvs_msgs/msg/Event"](x=int(a), y=int(b), ts=stamp(c), polarity=bool(d))
                for a, b, c, d in zip(x, y, t, p, strict=True)
            ]
            msg = types["dvs_msgs/msg/EventArray"](
                header=Header(seq=seq, stamp=stamp(t[0]), frame_id="cam"),
                height=180,
                width=240,
                events=events,
            )
            writer.write(ev_conn, int(t[0]) * 1000, store.serialize_ros1(msg, msg.__msgtype__))
        Vector3, Quaternion = (
            types["geometry_msgs/msg/Vector3"],
            types["geometry_msgs/msg/Quaternion"],
        )
        for seq, (t_us, w) in enumerate(imu):
            msg = types["sensor_msgs/msg/Imu"](
                header=Header(seq=seq, stamp=stamp(t_us), frame_id="imu"),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=Vector3(x=w[0], y=w[1], z=w[2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=Vector3(x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=np.zeros(9),
            )
            writer.write(imu_conn, int(t_us) * 1000, store.serialize_ros1(msg, msg.__msgtype__))


def test_rosbag_round_trip(tmp_path, monkeypatch, capsys):
    t0 = 1_700_000_000_000_000  # µs since the epoch, as ROS stamps are: far past 2^32
    x, y, t, p = random_events(900, 240, 180, t0, 90_000, seed=6)
    parts = np.array_split(np.arange(900), 9)
    order = [0, 2, 1, 3, 4, 6, 5, 7, 8]  # messages 10 ms out of order
    imu = [(t0 + 5000 * k, (0.1 * k, -0.2, 0.3)) for k in range(10)]
    path = tmp_path / "rec.bag"
    write_bag(path, [(x[parts[k]], y[parts[k]], t[parts[k]], p[parts[k]]) for k in order], imu)
    assert detect_format(path) == "rosbag"
    rec = read_recording(path)
    assert rec.events.sensor_size == (240, 180)
    assert rec.attrs["events_topic"] == "/dvs/events"
    assert_events(rec.events, x, y, t, p)
    chunks = list(iter_event_chunks(path, chunk_events=64))
    assert_events(EventArray.concatenate(chunks), x, y, t, p)
    gyro = read_gyro(path, imu_to_camera=imu_rotation("-x,-y,z"))
    np.testing.assert_array_equal(gyro.t, [s for s, _ in imu])
    np.testing.assert_allclose(gyro.omega, [(-0.1 * k, 0.2, 0.3) for k in range(10)])
    empty = tmp_path / "empty.bag"
    write_bag(empty, [])
    assert len(read_recording(empty, sensor=(240, 180)).events) == 0
    bad = tmp_path / "bad.bag"
    bad.write_bytes(path.read_bytes()[:-200])
    assert "bad.bag" in cli_error(monkeypatch, capsys, "info", str(bad))


# --- convert -------------------------------------------------------------------------------------


def test_convert_between_our_formats_streams_exactly(tmp_path, monkeypatch, capsys):
    x, y, t, p = random_events(5000, 240, 180, BIG_T0, 500_000, seed=7)
    gyro = GyroTrace.from_arrays(BIG_T0 + np.arange(0, 500_000, 1000), np.ones((500, 3)))
    rec = Recording(EventArray.from_arrays(x, y, t, p, 240, 180), gyro, {"fx": 200.0})
    src = write_recording(tmp_path / "src.h5", rec)
    previous = src
    for name in ("a.npz", "b", "c.h5"):
        out = tmp_path / name
        n_events, n_gyro = convert(previous, out, chunk_events=333)
        assert (n_events, n_gyro) == (5000, 500)
        back = read_recording(out)
        assert_events(back.events, x, y, t, p)
        np.testing.assert_array_equal(back.gyro.t, gyro.t)
        np.testing.assert_allclose(back.gyro.omega, gyro.omega, rtol=1e-8)
        previous = out
    assert read_recording(tmp_path / "a.npz").attrs["fx"] == 200.0
    err = cli_error(monkeypatch, capsys, "convert", str(src), str(tmp_path / "out.xyz"))
    assert "out.xyz" in err and not (tmp_path / "out.xyz").exists()


@pytest.mark.parametrize("suffix", [".aedat4", ".raw", ".dat"])
def test_convert_to_camera_formats(tmp_path, suffix):
    pytest.importorskip("faery")
    if suffix == ".aedat4":
        pytest.importorskip("aedat")
    # DAT keeps 32-bit timestamps: a recording that crosses 2^32 µs comes back through the wrap.
    x, y, t, p = random_events(4000, 640, 480, (1 << 32) - 150_000, 300_000, seed=8)
    src = write_recording(
        tmp_path / "src.h5", Recording(EventArray.from_arrays(x, y, t, p, 640, 480))
    )
    out = tmp_path / f"out{suffix}"
    assert convert(src, out, chunk_events=1000) == (4000, 0)
    back = read_recording(out)
    assert back.events.sensor_size == (640, 480)
    assert_events(back.events, x, y, t, p)


def test_ros2_bag_folder(tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer

    from spikegyro.events.rosbag import typestore

    store = typestore(ros2=True)
    types = store.types
    Time = types["builtin_interfaces/msg/Time"]
    x, y, t, p = random_events(300, 240, 180, 1_700_000_000_000_000, 50_000, seed=9)
    path = tmp_path / "bag2"
    with Writer(path, version=8) as writer:
        conn = writer.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        for k, part in enumerate(np.array_split(np.arange(300), 3)[::-1]):  # newest first
            events = [
                types["dvs_msgs/msg/Event"](
                    x=int(x[i]),
                    y=int(y[i]),
                    ts=Time(sec=int(t[i]) // 1_000_000, nanosec=int(t[i]) % 1_000_000 * 1000),
                    polarity=bool(p[i]),
                )
                for i in part
            ]
            header = types["std_msgs/msg/Header"](stamp=Time(sec=0, nanosec=0), frame_id="cam")
            msg = types["dvs_msgs/msg/EventArray"](
                header=header, height=180, width=240, events=events
            )
            writer.write(conn, k + 1, store.serialize_cdr(msg, msg.__msgtype__))
    assert detect_format(path) == "rosbag"
    assert_events(read_recording(path).events, x, y, t, p)


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_convert_memory_does_not_grow_with_the_file(tmp_path, suffix):
    import tracemalloc

    peaks = []
    for n in (100_000, 400_000):
        x, y, t, p = random_events(n, 240, 180, 0, 10 * n, seed=10)
        rec = Recording(EventArray.from_arrays(x, y, t, p, 240, 180))
        src = write_recording(tmp_path / f"src{n}.h5", rec)
        tracemalloc.start()
        try:
            convert(src, tmp_path / f"out{n}{suffix}", chunk_events=5000)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        assert_events(read_recording(tmp_path / f"out{n}{suffix}").events, x, y, t, p)
    # Four times the events (5.2 MB of them in memory) leave the peak where it was.
    assert peaks[1] < 1.25 * peaks[0] + 100_000, peaks
    assert peaks[1] < 400_000 * 13 / 3
