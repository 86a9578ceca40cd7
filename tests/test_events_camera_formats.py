"""Camera formats read from bytes built here by hand from each format's specification.

jAER AEDAT 2.0 / 3.1 and Prophesee DAT / EVT 2.0 / EVT 3.0 need no optional package, so these
tests run in the default suite. Each writer below encodes the bit layout the spec gives (not the
reader's code), and every test reads the events back exactly: timestamps past 2^32 µs (through
the formats' counter wrap-arounds), packets out of order, empty files, and damaged files.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from format_helpers import assert_events, cli_error, cli_run

from spikegyro.errors import InputError, InputWarning
from spikegyro.events.imu import imu_rotation
from spikegyro.events.io import detect_format, iter_event_chunks, read_gyro, read_recording

BIG_T0 = (1 << 32) + 12_345  # µs, past 2^32


def random_events(n: int, width: int, height: int, t0: int, span: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(t0, t0 + span, n))
    return rng.integers(0, width, n), rng.integers(0, height, n), t, rng.integers(0, 2, n)


def streamed(path: Path, chunk_events: int = 97, **kw):
    chunks = list(iter_event_chunks(path, chunk_events=chunk_events, **kw))
    assert all(len(c) <= chunk_events for c in chunks)
    return chunks


# --- jAER AEDAT 2.0: big-endian (uint32 address, int32 timestamp) records -----------------------

JAER_HEADER = b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C\r\n"


def jaer_dvs(x: int, y_up: int, p: int) -> int:
    return (y_up << 22) | (x << 12) | (p << 11)


def jaer_imu(channel: int, value: int) -> int:
    return (1 << 31) | (channel << 28) | ((value & 0xFFFF) << 12) | (3 << 10)


def jaer_bytes(records: list[tuple[int, int]]) -> bytes:
    return JAER_HEADER + b"".join(struct.pack(">II", a, t % (1 << 32)) for a, t in records)


def test_jaer2_events_imu_wrap_and_order(tmp_path):
    x, y, t, p = random_events(400, 240, 180, BIG_T0 - 200_000, 400_000)
    # The second half of the events (past the 2^32 µs wrap of the 32-bit counter) is written
    # first out of order by one 2 ms "packet".
    records = [
        (jaer_dvs(int(a), 179 - int(b), int(c)), int(d))
        for a, b, c, d in zip(x, y, p, t, strict=True)
    ]
    records[200:210], records[210:220] = records[210:220], records[200:210]
    gyro_raw = np.array([[328, -656, 32], [-100, 50, 3280]])  # LSB, 32.8 per deg/s
    for k, (t_imu, g) in enumerate(zip((BIG_T0 - 1000, BIG_T0 + 1000), gyro_raw, strict=True)):
        words = [jaer_imu(c, v) for c, v in enumerate([1, 2, 3, 4, *g])]
        records[100 + 50 * k : 100 + 50 * k] = [(w, t_imu) for w in words]
    records.insert(5, ((1 << 31) | (7 << 12), int(t[5])))  # an APS sample: skipped
    records.insert(9, (jaer_dvs(3, 3, 1) | (1 << 10), int(t[9])))  # a trigger: skipped
    path = tmp_path / "rec.aedat"
    path.write_bytes(jaer_bytes(records))
    assert detect_format(path) == "jaer2"
    rec = read_recording(path, imu_to_camera=imu_rotation("-x,-y,z"))
    assert rec.events.sensor_size == (240, 180)
    assert_events(rec.events, x, y, t, p)
    np.testing.assert_array_equal(rec.gyro.t, [BIG_T0 - 1000, BIG_T0 + 1000])
    expected = np.radians(gyro_raw / 32.8) * [-1, -1, 1]
    np.testing.assert_allclose(rec.gyro.omega, expected, rtol=1e-12)
    np.testing.assert_allclose(read_gyro(path).omega, expected * [-1, -1, 1], rtol=1e-12)
    chunks = streamed(path)
    assert_events(type(rec.events).concatenate(chunks), x, y, t, p)


def test_jaer2_empty_and_truncated(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "empty.aedat"
    empty.write_bytes(JAER_HEADER)
    assert len(read_recording(empty).events) == 0
    assert list(iter_event_chunks(empty)) == []
    # Cut inside the last record: the records before it are read, with one warning line.
    cut = tmp_path / "cut.aedat"
    cut.write_bytes(jaer_bytes([(jaer_dvs(1, 2, 1), 5), (jaer_dvs(3, 4, 0), 9)])[:-3])
    with pytest.warns(InputWarning, match="truncated"):
        assert_events(read_recording(cut).events, [1], [177], [5], [1])
    _, err = cli_run(monkeypatch, capsys, "info", str(cut))
    assert err.startswith("warning: ") and err.count("\n") == 1 and "cut.aedat" in err
    # Cut inside jAER's (long) header, in its preferences: nothing to read, an error.
    prefs = "".join(f"#<entry key='k{i}' value='{i}'/>\r\n" for i in range(2000))
    header = JAER_HEADER + f"#<preferences>\r\n{prefs}#</preferences>\r\n".encode()
    whole = header + jaer_bytes([(jaer_dvs(1, 2, 1), 5)])[len(JAER_HEADER) :]
    assert len(read_recording(_written(tmp_path / "whole.aedat", whole)).events) == 1
    for cut_at in (len(header) // 2, len(header) - 5, len(JAER_HEADER) + 12):
        bad = _written(tmp_path / "bad.aedat", whole[:cut_at])
        with pytest.raises(InputError, match="ends inside its text header"):
            read_recording(bad)
    err = cli_error(monkeypatch, capsys, "info", str(bad))
    assert "bad.aedat" in err and "truncated" in err


def _written(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# --- jAER / cAER AEDAT 3.1: little-endian packets -----------------------------------------------


def caer_packet(kind: int, size: int, overflow: int, payload: bytes, n: int) -> bytes:
    return struct.pack("<hhiiiiii", kind, 1, size, 4, overflow, n, n, n) + payload


def test_aedat31_polarity_and_imu(tmp_path):
    x, y, t, p = random_events(300, 346, 260, BIG_T0 - 100_000, 200_000, seed=1)
    packets = []
    for half in (np.arange(150, 300), np.arange(0, 150)):  # second half first: out of order
        for overflow in np.unique(t[half] >> 31):  # a packet holds one overflow period
            idx = half[t[half] >> 31 == overflow]
            data = (x[idx] << 17) | (y[idx] << 2) | (p[idx] << 1) | 1
            low = t[idx] - (overflow << 31)
            payload = b"".join(
                struct.pack("<Ii", int(d), int(s)) for d, s in zip(data, low, strict=True)
            )
            packets.append(caer_packet(1, 8, int(overflow), payload, len(idx)))
    invalid = struct.pack("<Ii", (5 << 17) | (5 << 2), 7)  # valid bit clear: skipped
    packets.append(caer_packet(1, 8, 0, invalid, 1))
    imu_t = BIG_T0 + 500
    imu = struct.pack("<Ii7f", 1, imu_t - (2 << 31), 0, 0, 1, 10.0, -20.0, 30.0, 25.0)
    packets.append(caer_packet(3, 36, 2, imu, 1))
    packets.append(caer_packet(2, 4, 0, b"\0" * 4, 1))  # a frame packet: skipped
    path = tmp_path / "rec.aedat"
    header = b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: DAVIS346B\r\n#!END-HEADER\r\n"
    path.write_bytes(header + b"".join(packets))
    assert detect_format(path) == "jaer3"
    rec = read_recording(path)
    assert rec.events.sensor_size == (346, 260)
    assert_events(rec.events, x, y, t, p)
    np.testing.assert_array_equal(rec.gyro.t, [imu_t])
    np.testing.assert_allclose(rec.gyro.omega, np.radians([[10.0, -20.0, 30.0]]), rtol=1e-6)
    assert_events(type(rec.events).concatenate(streamed(path)), x, y, t, p)
    # A packet 150 ms older than the one before: past the streaming reorder window (one line),
    # while a whole-file read still sorts it in.
    late = struct.pack("<Ii", (7 << 17) | (8 << 2) | 1, int(t[-1] - (2 << 31)) - 150_000)
    path.write_bytes(header + b"".join(packets) + caer_packet(1, 8, 2, late, 1))
    assert len(read_recording(path).events) == len(t) + 1
    with pytest.raises(InputError, match="out of time order by more than 100 ms"):
        streamed(path)
    path.write_bytes(header + b"".join(packets)[:-3])  # the last (frame) packet is cut
    with pytest.warns(InputWarning, match="truncated"):
        rec = read_recording(path)
    assert_events(rec.events, x, y, t, p)
    np.testing.assert_array_equal(rec.gyro.t, [imu_t])


# --- Prophesee DAT -------------------------------------------------------------------------------


def dat_bytes(x, y, t, p, width=640, height=480) -> bytes:
    header = f"% Date 2024-01-01\n% Version 2\n% Width {width}\n% Height {height}\n".encode()
    x, y, p = (np.asarray(v, dtype=np.int64) for v in (x, y, p))
    data = (x | (y << 14) | (p << 28)).astype("<u4")
    table = np.column_stack([(np.asarray(t) % (1 << 32)).astype("<u4"), data])
    return header + bytes([0, 8]) + table.astype("<u4").tobytes()


def test_dat_round_trip_wrap_and_order(tmp_path):
    x, y, t, p = random_events(500, 640, 480, BIG_T0 - 300_000, 600_000, seed=2)
    t_file = t.copy()
    t_file[300:305] -= 3000  # a few events 3 ms late in the file: put back in order
    path = tmp_path / "cam.dat"
    path.write_bytes(dat_bytes(x, y, t_file, p))
    assert detect_format(path) == "prophesee_dat"
    rec = read_recording(path)
    assert rec.events.sensor_size == (640, 480)
    assert_events(rec.events, x, y, t_file, p)
    assert_events(type(rec.events).concatenate(streamed(path)), x, y, t_file, p)
    empty = tmp_path / "empty.dat"
    empty.write_bytes(dat_bytes([], [], [], []))
    assert len(read_recording(empty).events) == 0
    path.write_bytes(dat_bytes(x, y, t, p)[:-5])
    with pytest.warns(InputWarning, match="truncated"):
        assert_events(read_recording(path).events, x[:-1], y[:-1], t[:-1], p[:-1])


def test_text_dat_is_still_text(tmp_path):
    path = tmp_path / "events.dat"
    path.write_text("0.001 3 4 1\n0.002 5 6 0\n")
    assert detect_format(path) == "events_txt"
    bad = tmp_path / "cam.raw"
    bad.write_bytes(b"\x00\x01garbage")
    with pytest.raises(InputError, match="not a Prophesee RAW file"):
        detect_format(bad)


# --- Prophesee RAW EVT 2.0 -----------------------------------------------------------------------


def evt2_bytes(x, y, t, p, extra: list[tuple[int, int]] = ()) -> bytes:
    header = (
        b"% camera_integrator_name Prophesee\n% evt 2.0\n"
        b"% format EVT2;height=720;width=1280\n% end\n"
    )
    words = []
    high = None
    for a, b, c, d in zip(x, y, t, p, strict=True):
        if c >> 6 != high:
            high = int(c) >> 6
            words.append((8 << 28) | (high & 0x0FFFFFFF))
        words.append((int(d) << 28) | ((int(c) & 63) << 22) | (int(a) << 11) | int(b))
    for pos, word in extra:
        words.insert(pos, word)
    return header + np.array(words, dtype="<u4").tobytes()


def test_evt2_round_trip_past_34_bits(tmp_path):
    # The EVT 2.0 clock is 34 bits: start past 2^32 and run across its 2^34 µs wrap.
    x, y, t, p = random_events(600, 1280, 720, (1 << 34) - 300_000, 600_000, seed=3)
    # External trigger words (level in bit 0, id in bits 8-12): counted apart, not events.
    triggers = [(10, (0xA << 28) | (2 << 8) | 1), (20, (0xA << 28) | (2 << 8)), (30, 0xA << 28)]
    path = tmp_path / "cam.raw"
    path.write_bytes(evt2_bytes(x, y, t, p, extra=triggers))
    assert detect_format(path) == "prophesee_raw"
    rec = read_recording(path)
    assert rec.events.sensor_size == (1280, 720)
    assert rec.attrs["prophesee_camera_integrator_name"] == "Prophesee"
    assert (rec.attrs["triggers_rising"], rec.attrs["triggers_falling"]) == (1, 2)
    assert_events(rec.events, x, y, t, p)
    assert_events(type(rec.events).concatenate(streamed(path)), x, y, t, p)


# --- Prophesee RAW EVT 3.0 -----------------------------------------------------------------------


def evt3_bytes(groups) -> bytes:
    """``groups``: (t, y, polarity, xs) with xs all at one time, row and polarity."""
    header = b"% evt 3.0\n% geometry 640x480\n% end\n"
    words: list[int] = []
    high = low = None
    for t, y, p, xs in groups:
        if t >> 12 & 0xFFF != high:
            high = t >> 12 & 0xFFF
            words.append((0x8 << 12) | high)
        if t & 0xFFF != low:
            low = t & 0xFFF
            words.append((0x6 << 12) | low)
        words.append(y)  # EVT_ADDR_Y: type 0
        xs = sorted(xs)
        if len(xs) == 1:
            words.append((0x2 << 12) | (p << 11) | xs[0])
            continue
        base = xs[0]
        words.append((0x3 << 12) | (p << 11) | base)
        while base <= xs[-1]:  # alternate 12- and 8-wide vectors
            width = 12 if len(words) % 2 else 8
            mask = sum(1 << (v - base) for v in xs if base <= v < base + width)
            words.append(((0x4 if width == 12 else 0x5) << 12) | mask)
            base += width
    return header + np.array(words, dtype="<u2").tobytes()


def test_evt3_vectors_and_wraps_past_2_32(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(4)
    # Steps of up to 2^22 µs: the 24-bit clock wraps over 256 times before t passes 2^32.
    steps = rng.integers(0, 1 << 22, 2200)
    times = np.cumsum(steps) + 17
    assert times[-1] > 1 << 32
    groups, expected = [], []
    for k, t in enumerate(times):
        y, p = int(rng.integers(0, 480)), int(rng.integers(0, 2))
        n = 1 if k % 3 else int(rng.integers(2, 30))
        xs = sorted(set(rng.integers(0, 600, n).tolist())) if n > 1 else [int(rng.integers(0, 640))]
        if k % 3 == 0 and len(xs) > 1:
            xs = sorted({xs[0] + int(d) for d in rng.integers(0, 40, n)} & set(range(640)))
        groups.append((int(t), y, p, xs))
        expected += [(v, y, int(t), p) for v in xs]
    path = tmp_path / "cam.raw"
    path.write_bytes(evt3_bytes(groups))
    rec = read_recording(path)
    assert rec.events.sensor_size == (640, 480)
    x, y, t, p = (np.array(col) for col in zip(*expected, strict=True))
    assert_events(rec.events, x, y, t, p)
    assert_events(type(rec.events).concatenate(streamed(path, 1000)), x, y, t, p)
    empty = tmp_path / "empty.raw"
    empty.write_bytes(evt3_bytes([]))
    assert len(read_recording(empty).events) == 0
    path.write_bytes(evt3_bytes(groups)[:-1])
    _, err = cli_run(monkeypatch, capsys, "info", str(path))
    assert err.startswith("warning: ") and "truncated" in err and err.count("\n") == 1


def test_unsupported_raw_encoding(tmp_path):
    path = tmp_path / "cam.raw"
    path.write_bytes(b"% format EVT21;height=720;width=1280\n% end\n" + b"\0" * 8)
    with pytest.raises(InputError, match="evt21"):
        read_recording(path)


def test_imu_rotation_spellings():
    r = imu_rotation("-x,-y,z")
    np.testing.assert_array_equal(r, np.diag([-1.0, -1.0, 1.0]))
    r = imu_rotation("y, -x, z")
    np.testing.assert_array_equal(r @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0])
    np.testing.assert_array_equal(imu_rotation("0 1 0 -1 0 0 0 0 1"), r)
    for bad in ("x,x,z", "-x,y,z", "1 2 3", "a,b,c"):
        with pytest.raises(InputError):
            imu_rotation(bad)
