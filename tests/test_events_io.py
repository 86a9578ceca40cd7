"""Round-trips through every file format, format detection, and every bad-input error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from spikegyro.errors import InputError
from spikegyro.events import EventArray, GyroTrace, Recording, read_recording, write_recording
from spikegyro.events.io import detect_format, iter_event_chunks, read_gyro


def make_recording(n: int = 5000, seed: int = 0, width: int = 240, height: int = 180) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 500_000, n))
    events = EventArray.from_arrays(
        rng.integers(0, width, n),
        rng.integers(0, height, n),
        t,
        rng.integers(0, 2, n),
        width,
        height,
    )
    gyro_t = np.arange(0, 500_001, 1000)
    gyro = GyroTrace.from_arrays(gyro_t, rng.normal(0, 2.0, (gyro_t.size, 3)))
    return Recording(events, gyro, {"fx": 200.0, "scene": "unit-test", "seed": seed})


def assert_same_events(a: EventArray, b: EventArray) -> None:
    for name in ("x", "y", "t", "p"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.sensor_size == b.sensor_size


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_binary_formats_round_trip_exactly(tmp_path: Path, suffix: str) -> None:
    rec = make_recording(width=346, height=260)
    path = write_recording(tmp_path / f"seq{suffix}", rec)
    back = read_recording(path)
    assert_same_events(rec.events, back.events)
    np.testing.assert_array_equal(rec.gyro.t, back.gyro.t)
    np.testing.assert_array_equal(rec.gyro.omega, back.gyro.omega)
    assert back.attrs["scene"] == "unit-test"
    assert back.attrs["fx"] == 200.0


def test_hdf5_uses_official_layout(tmp_path: Path) -> None:
    rec = make_recording()
    path = write_recording(tmp_path / "seq.h5", rec)
    with h5py.File(path, "r") as f:
        assert f["ev_xy"].shape == (len(rec.events), 2)
        assert f["ev_ts"].shape == (len(rec.events),)
        assert f["ev_pol"].shape == (len(rec.events),)
        assert f["ang_xyz"].shape == (len(rec.gyro), 3)
        assert f["ang_ts"].shape == (len(rec.gyro),)
        np.testing.assert_array_equal(f["ev_xy"][:, 0], rec.events.x)


def test_official_file_without_attributes_reads_as_davis240(tmp_path: Path) -> None:
    path = tmp_path / "official.h5"
    with h5py.File(path, "w") as f:
        f["ev_xy"] = np.array([[0, 0], [239, 179]])
        f["ev_ts"] = np.array([10, 20])
        f["ev_pol"] = np.array([1, 0])
        f["ang_xyz"] = np.zeros((2, 3))
        f["ang_ts"] = np.array([0, 1000])
    rec = read_recording(path)
    assert rec.events.sensor_size == (240, 180)
    assert len(rec.events) == 2


def test_text_events_round_trip_to_the_microsecond(tmp_path: Path) -> None:
    rec = make_recording()
    path = write_recording(tmp_path / "events.txt", Recording(rec.events))
    assert detect_format(path) == "events_txt"
    assert_same_events(rec.events, read_recording(path).events)


def test_event_camera_dataset_folder_with_imu(tmp_path: Path) -> None:
    rec = make_recording()
    write_recording(tmp_path / "events.txt", Recording(rec.events))
    imu = np.column_stack([rec.gyro.t / 1e6, np.zeros((len(rec.gyro), 3)), rec.gyro.omega])
    np.savetxt(tmp_path / "imu.txt", imu, fmt="%.9f")
    assert detect_format(tmp_path / "imu.txt") == "imu_txt"
    back = read_recording(tmp_path)
    assert_same_events(rec.events, back.events)
    np.testing.assert_allclose(back.gyro.omega, rec.gyro.omega, atol=1e-8)
    np.testing.assert_array_equal(back.gyro.t, rec.gyro.t)


def test_folder_write_and_plain_gyro_file(tmp_path: Path) -> None:
    rec = make_recording()
    folder = write_recording(tmp_path / "rec", rec)
    assert detect_format(folder / "gyro.txt") == "gyro_txt"
    gyro = read_gyro(folder / "gyro.txt")
    np.testing.assert_allclose(gyro.omega, rec.gyro.omega, rtol=1e-8)
    back = read_recording(folder)
    assert_same_events(rec.events, back.events)
    assert back.gyro is not None


def test_gyro_interpolation_is_linear() -> None:
    gyro = GyroTrace.from_arrays([0, 1000], [[0.0, 1.0, -2.0], [1.0, 3.0, 2.0]])
    np.testing.assert_allclose(gyro.interpolate(np.array([250])), [[0.25, 1.5, -1.0]])


@pytest.mark.parametrize("suffix", [".h5", ".txt"])
def test_chunked_reading_equals_whole_file(tmp_path: Path, suffix: str) -> None:
    rec = make_recording(n=20_000)
    path = write_recording(tmp_path / f"events{suffix}", Recording(rec.events))
    chunks = list(iter_event_chunks(path, chunk_events=3000))
    assert len(chunks) > 2
    assert_same_events(rec.events, EventArray.concatenate(chunks))


def test_slice_time_is_half_open() -> None:
    ev = EventArray.from_arrays(
        [1, 2, 3, 4], [0, 0, 0, 0], [0, 1000, 1999, 2000], [1, 0, 1, 0], 8, 8
    )
    part = ev.slice_time(1000, 2000)
    np.testing.assert_array_equal(part.t, [1000, 1999])


def test_rescale_maps_onto_smaller_sensor() -> None:
    ev = EventArray.from_arrays([0, 1, 239], [0, 3, 179], [0, 1, 2], [1, 1, 0], 240, 180)
    half = ev.rescale(0.5)
    assert half.sensor_size == (120, 90)
    np.testing.assert_array_equal(half.x, [0, 0, 119])
    np.testing.assert_array_equal(half.y, [0, 1, 89])


# --- bad input: one clear error naming the file and the problem ---------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_recording(tmp_path / "nope.h5")


def test_unknown_format(tmp_path: Path) -> None:
    (tmp_path / "x.bin").write_bytes(b"\0\1")
    with pytest.raises(InputError, match="unknown format"):
        read_recording(tmp_path / "x.bin")


def test_hdf5_missing_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.h5"
    with h5py.File(path, "w") as f:
        f["ev_xy"] = np.zeros((3, 2))
        f["ev_pol"] = np.zeros(3)
    with pytest.raises(InputError, match="ev_ts"):
        read_recording(path)


def test_events_outside_sensor(tmp_path: Path) -> None:
    path = tmp_path / "events.txt"
    path.write_text("0.1 10 10 1\n0.2 300 10 0\n")
    with pytest.raises(InputError, match="outside the 240x180 sensor"):
        read_recording(path)


def test_unsorted_timestamps(tmp_path: Path) -> None:
    path = tmp_path / "events.txt"
    path.write_text("0.2 10 10 1\n0.1 11 10 0\n")
    with pytest.raises(InputError, match="not sorted"):
        read_recording(path)


def test_unsorted_across_chunks(tmp_path: Path) -> None:
    rec = make_recording(n=4000)
    t = rec.events.t.copy()
    t[3000:] -= 400_000
    bad = EventArray.from_arrays(
        rec.events.x, rec.events.y, t, rec.events.p, 240, 180, validate=False
    )
    path = write_recording(tmp_path / "bad.h5", Recording(bad))
    with pytest.raises(InputError, match="not sorted"):
        list(iter_event_chunks(path, chunk_events=1000))


def test_empty_window_error() -> None:
    from spikegyro.events.representations import check_window

    with pytest.raises(InputError, match="no events in the window"):
        check_window(0, "rec.h5", 0, 1000)


def test_malformed_text_line(tmp_path: Path) -> None:
    path = tmp_path / "events.txt"
    path.write_text("0.1 10 10 1\n0.2 11 10\n")
    with pytest.raises(InputError, match="malformed"):
        read_recording(path)


@pytest.mark.parametrize(
    ("body", "bad"),
    [
        ("0.1 1 2 1\nfoo bar\n0.2 3 4 0\n", "foo bar"),  # words after the data began
        ("0.1 1 2 1\n0.2 3 4 0\n0.3 5 6 1 extra\n", "0.3 5 6 1 extra"),
        ("0.1 1 2 1\n0.2 3 4 0 0.3 5 6 1\n0.4 1 1 1\n", "0.2 3 4 0 0.3 5 6 1"),  # 8 numbers
    ],
)
def test_a_bad_row_anywhere_is_named_not_skipped(tmp_path: Path, body: str, bad: str) -> None:
    path = tmp_path / "events.txt"
    path.write_text(body)
    with pytest.raises(InputError, match=f"the line '{bad}'"):
        read_recording(path)


def test_header_comments_and_blank_lines_are_not_rows(tmp_path: Path) -> None:
    path = tmp_path / "events.txt"
    path.write_text("t x y p\n# DAVIS240C\n0.1 1 2 1\n\n0.2 3 4 0\n   \n")
    ev = read_recording(path).events
    np.testing.assert_array_equal(ev.t, [100_000, 200_000])
    np.testing.assert_array_equal(ev.x, [1, 3])


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    rec = make_recording()
    bad = Recording(rec.events, rec.gyro, {"bad": object()})
    with pytest.raises(TypeError):
        write_recording(tmp_path / "out.h5", bad)
    assert list(tmp_path.iterdir()) == []


def test_cli_prints_one_line_and_exits_2(tmp_path: Path) -> None:
    path = tmp_path / "events.txt"
    path.write_text("0.2 10 10 1\n0.1 11 10 0\n")
    proc = subprocess.run(
        [sys.executable, "-m", "spikegyro", "info", str(path)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "not sorted" in lines[0]


def test_cli_info_summarises(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "seq.h5", make_recording())
    proc = subprocess.run(
        [sys.executable, "-m", "spikegyro", "info", str(path)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert "5,000" in proc.stdout and "240 x 180" in proc.stdout


def test_written_files_get_default_permissions(tmp_path: Path) -> None:
    import os

    umask = os.umask(0o022)
    try:
        path = write_recording(tmp_path / "seq.h5", make_recording(n=10))
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644


def test_a_time_span_read_from_hdf5_equals_the_slice_of_the_whole_file(tmp_path: Path) -> None:
    """Spans starting and ending anywhere: before the first event, on the index's own
    timestamps (every 4096th event), between two equal timestamps, past the last event."""
    from spikegyro.events.io import HDF5_INDEX_STRIDE, index_hdf5, read_hdf5_span

    rec = make_recording(n=3 * HDF5_INDEX_STRIDE + 77, seed=4)
    rec.events.t[100:110] = rec.events.t[100]  # a run of equal timestamps
    path = tmp_path / "seq.h5"
    write_recording(path, rec)
    whole = read_recording(path).events
    index = index_hdf5(path)
    assert index.count == len(whole) and index.sensor == (240, 180)
    t = whole.t
    marks = [t[0] - 5, t[0], t[105], t[HDF5_INDEX_STRIDE], t[HDF5_INDEX_STRIDE] + 1,
             t[2 * HDF5_INDEX_STRIDE] - 1, t[-1], t[-1] + 1]  # fmt: skip
    rng = np.random.default_rng(0)
    spans = [(a, b) for a in marks for b in marks if a <= b]
    spans += [tuple(sorted(rng.integers(t[0], t[-1], 2))) for _ in range(20)]
    for a, b in spans:
        assert_same_events(read_hdf5_span(path, int(a), int(b), index), whole.slice_time(a, b))
    assert_same_events(read_hdf5_span(path, int(t[0]), int(t[-1]) + 1), whole)
