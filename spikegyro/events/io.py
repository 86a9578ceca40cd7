"""Readers and writers for event and gyro files, with format detection by extension and content.

Formats (``detect_format`` names):

- ``hdf5``: the official layout of the paper's dataset (datasets ``ev_xy`` (N, 2), ``ev_ts`` (N,)
  microseconds, ``ev_pol`` (N,) 0/1, ``ang_xyz`` (K, 3) rad/s, ``ang_ts`` (K,) microseconds) and our
  sequence files, which add HDF5 attributes (``width``, ``height``, intrinsics, thresholds, ...).
- ``npz``: arrays ``x, y, t, p`` (+ ``gyro_t``, ``gyro_omega``), ``width``, ``height``, ``attrs``.
- ``events_txt``: Event Camera Dataset ``events.txt``, one event per line ``t x y p``, t in seconds.
- ``imu_txt``: ``t ax ay az gx gy gz`` (seconds, m/s^2, rad/s); only the gyro is kept.
- ``gyro_txt``: ``t wx wy wz`` (seconds, rad/s).
- ``ecd_dir``: a folder holding ``events.txt`` and optionally ``imu.txt`` or ``gyro.txt``.
- camera formats, each in its own module and recognised by its header, whatever the extension:
  ``aedat4`` (iniVation DV, :mod:`~spikegyro.events.aedat4`), ``jaer2`` / ``jaer3`` (jAER AEDAT
  2.0 / 3.1, :mod:`~spikegyro.events.jaer`), ``prophesee_raw`` (EVT 2.0 / 3.0) and
  ``prophesee_dat`` (:mod:`~spikegyro.events.prophesee`), ``rosbag`` (ROS 1 bags, ROS 2 bag
  folders, :mod:`~spikegyro.events.rosbag`). Their gyro samples are in the IMU's own axes unless
  ``imu_to_camera`` (see :func:`spikegyro.events.imu.imu_rotation`) is given.

Text files are parsed block by block with NumPy (no Python object per line), so multi-GB files
read at disk speed and :func:`iter_event_chunks` streams them in bounded memory.
"""

from __future__ import annotations

import functools
import inspect
import json
import os
import re
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import h5py
import numpy as np

from spikegyro.errors import InputError
from spikegyro.events import aedat4, jaer, prophesee, rosbag
from spikegyro.events.blocks import (
    gyro_from_blocks,
    recording_from_blocks,
    sensor_of,
    sorted_chunks,
)
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.imu import imu_rotation, rotate_to_camera

DEFAULT_SENSOR = (240, 180)
OFFICIAL_KEYS = ("ev_xy", "ev_ts", "ev_pol", "ang_xyz", "ang_ts")
_TEXT_BLOCK_BYTES = 1 << 24
_CAMERA_MODULES = (aedat4, jaer, prophesee, rosbag)
CAMERA_FORMATS = {fmt: module for module in _CAMERA_MODULES for fmt in module.FORMATS}
_CAMERA_SUFFIXES = {
    ".aedat4": "AEDAT 4",
    ".aedat": "AEDAT",
    ".raw": "Prophesee RAW",
    ".bag": "ROS bag",
}


_LOW_LEVEL_ERRORS = (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile)
"""What parsers, h5py and NumPy raise for a damaged or foreign file."""
_Reader = TypeVar("_Reader", bound=Callable[..., Any])


def _unreadable(path: Any, exc: BaseException) -> InputError:
    detail = " ".join(str(exc).split()) or type(exc).__name__
    return InputError(
        f"{path}: cannot be read ({type(exc).__name__}: {detail[:200]}); check that it is a "
        "complete file of a supported format (see spikegyro info --help)."
    )


def reader_boundary(function: _Reader) -> _Reader:
    """Turn what a damaged or foreign file makes the low-level libraries raise into one
    :class:`InputError` naming the file (the first argument); generators are guarded too.

    Applied to the public readers only, so the commands never see a parser's exception."""
    if inspect.isgeneratorfunction(function):

        @functools.wraps(function)
        def generator(path: Any, *args: Any, **kwargs: Any) -> Iterator[Any]:
            try:
                yield from function(path, *args, **kwargs)
            except InputError:
                raise
            except _LOW_LEVEL_ERRORS as exc:
                raise _unreadable(path, exc) from exc

        return generator  # type: ignore[return-value]

    @functools.wraps(function)
    def plain(path: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return function(path, *args, **kwargs)
        except InputError:
            raise
        except _LOW_LEVEL_ERRORS as exc:
            raise _unreadable(path, exc) from exc

    return plain  # type: ignore[return-value]


EVENT_FILE_HELP = (
    "Event file: .h5/.hdf5, .npz, events.txt (t x y p), an ECD folder, .aedat4, jAER .aedat, "
    "Prophesee .raw/.dat or a ROS .bag (the format is detected from the content)."
)
"""Help text of the commands' event-file argument: what :func:`read_recording` reads."""


def _sniff_camera(path: Path) -> str | None:
    head = b""
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(4096)
    for module in _CAMERA_MODULES:
        fmt = module.sniff(path, head)
        if fmt:
            return fmt
    return None


@reader_boundary
def detect_format(path: str | os.PathLike) -> str:
    """Name the format of ``path`` from its extension and, for text, its first data line."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory.")
    camera = _sniff_camera(path)
    if camera:
        return camera
    suffix = path.suffix.lower()
    if suffix in _CAMERA_SUFFIXES:
        raise InputError(
            f"{path}: not a {_CAMERA_SUFFIXES[suffix]} file (its header is missing or damaged)."
        )
    if path.is_dir():
        if (path / "events.txt").exists():
            return "ecd_dir"
        raise InputError(f"{path}: a folder without events.txt; give an event file instead.")
    if suffix in (".h5", ".hdf5"):
        return "hdf5"
    if suffix == ".npz":
        return "npz"
    if suffix in (".txt", ".csv", ".dat"):
        first = _first_data_row(path)
        if first.size == 7:
            return "imu_txt"
        if first.size == 4:
            x, y, p = first[1], first[2], first[3]
            integral = x == int(x) and y == int(y) and p in (0.0, 1.0, -1.0)
            if integral and "gyro" not in path.name.lower():
                return "events_txt"
            return "gyro_txt"
        raise InputError(
            f"{path}: text file with {first.size} columns; expected 't x y p' events (4), "
            "'t wx wy wz' gyro (4) or 't ax ay az gx gy gz' IMU (7)."
        )
    raise InputError(
        f"{path}: unknown format '{suffix}'; use .h5/.hdf5, .npz, a .txt event/gyro file, "
        "AEDAT 2/3.1/4, Prophesee .raw/.dat or a ROS bag."
    )


def _first_data_row(path: Path) -> np.ndarray:
    with open(path, "rb") as f:
        for raw in f:
            line = raw.strip()
            if not line or line.startswith(b"#"):
                continue
            try:
                return np.array([float(v) for v in line.replace(b",", b" ").split()])
            except ValueError:
                continue  # a header line of names
    raise InputError(f"{path}: the file holds no data rows.")


def _iter_text_rows(
    path: Path, ncols: int, block_bytes: int = _TEXT_BLOCK_BYTES
) -> Iterator[np.ndarray]:
    """Yield (n, ncols) float64 blocks of a whitespace- or comma-separated numeric text file.

    Lines starting with ``#`` are comments; lines with words before the first data row are a
    header. Any other line that is not ``ncols`` numbers is an :class:`InputError` naming it.
    """
    carry, first = b"", True
    with open(path, "rb") as f:
        while True:
            block = f.read(block_bytes)
            data = carry + block
            if not block:
                carry = b""
            else:
                cut = data.rfind(b"\n")
                if cut < 0:
                    carry = data
                    continue
                data, carry = data[: cut + 1], data[cut + 1 :]
            if data.strip():
                rows = _parse_text_block(path, data, ncols, header_allowed=first)
                first = first and rows.size == 0
                yield rows
            if not block:
                return


_WORD = re.compile(rb"[A-DF-Za-df-z#]")
"""A letter other than an exponent's e/E, or a comment: the block needs the line-by-line path."""


def _parse_text_block(path: Path, data: bytes, ncols: int, header_allowed: bool) -> np.ndarray:
    text = data.decode("ascii", errors="replace").replace(",", " ")
    if _WORD.search(data):
        lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
        while header_allowed and lines and _WORD.search(lines[0].encode()):
            lines.pop(0)  # column names above the data
        text = "\n".join(lines)
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError:
        raise InputError(
            f"{path}: the line '{_first_bad_line(text, ncols)}' is not {ncols} numbers; fix or "
            "remove it."
        ) from None
    if values.size != ncols * _count_rows(text, values.size // max(ncols, 1)):
        raise InputError(
            f"{path}: the line '{_first_bad_line(text, ncols)}' does not have {ncols} numbers; "
            "fix or remove it."
        )
    return values.reshape(-1, ncols)


def _count_rows(text: str, expected: int) -> int:
    """Non-blank lines of ``text``: counted by newlines when that gives ``expected`` (the usual
    case, in C), else line by line (blank or whitespace-only lines)."""
    newlines = text.count("\n") + (0 if text.endswith("\n") else 1)
    if newlines == expected:
        return newlines
    return sum(1 for line in text.splitlines() if line.strip())


def _first_bad_line(text: str, ncols: int) -> str:
    for line in text.splitlines():
        fields = line.split()
        try:
            [float(v) for v in fields]
        except ValueError:
            return line.strip()[:80]
        if fields and len(fields) != ncols:
            return line.strip()[:80]
    return "?"


def _events_from_rows(rows: np.ndarray, sensor: tuple[int, int], source: str) -> EventArray:
    t_us = np.rint(rows[:, 0] * 1e6)
    return EventArray.from_arrays(
        rows[:, 1], rows[:, 2], t_us, rows[:, 3], sensor[0], sensor[1], source=source
    )


def _read_gyro_text(path: Path, kind: str) -> GyroTrace:
    ncols = 7 if kind == "imu_txt" else 4
    blocks = list(_iter_text_rows(path, ncols))
    rows = np.concatenate(blocks) if blocks else np.zeros((0, ncols))
    return GyroTrace.from_arrays(np.rint(rows[:, 0] * 1e6), rows[:, -3:], source=str(path))


def read_gyro(path: str | os.PathLike, *, imu_to_camera: np.ndarray | None = None) -> GyroTrace:
    """Read angular velocity from a gyro/IMU text file or any file that carries ground truth.

    ``imu_to_camera``: the 3x3 rotation R with ω_camera = R · ω_file (None: as in the file).
    """
    gyro = read_gyro_if_any(path, imu_to_camera=imu_to_camera)
    if gyro is None:
        raise InputError(f"{path}: the file holds no angular velocity (gyro) samples.")
    return gyro


@reader_boundary
def read_gyro_if_any(
    path: str | os.PathLike, *, imu_to_camera: np.ndarray | None = None
) -> GyroTrace | None:
    """The file's angular velocity, or None; event data are not read (except from ``.npz``)."""
    path = Path(path)
    kind = detect_format(path)
    if kind in CAMERA_FORMATS:
        module = CAMERA_FORMATS[kind]
        blocks = module.iter_blocks(path, module.read_header(path, kind), events=False)
        return gyro_from_blocks(blocks, imu_to_camera, str(path))
    gyro = None
    if kind in ("imu_txt", "gyro_txt"):
        gyro = _read_gyro_text(path, kind)
    elif kind == "ecd_dir":
        for name, gkind in (("imu.txt", "imu_txt"), ("gyro.txt", "gyro_txt")):
            if (path / name).exists():
                gyro = _read_gyro_text(path / name, gkind)
                break
    elif kind == "hdf5":
        with open_hdf5(path) as f:
            if "ang_xyz" in f or "ang_ts" in f:
                _require_keys(f, ("ang_xyz", "ang_ts"), path)
                gyro = GyroTrace.from_arrays(f["ang_ts"][()], f["ang_xyz"][()], source=str(path))
    elif kind == "npz":
        gyro = _read_npz(path, None).gyro
    if gyro is None:
        return None
    return replace(gyro, omega=rotate_to_camera(gyro.omega, imu_to_camera))


KNOWN_IMU_TO_CAMERA: dict[tuple[str, str], tuple[str, str]] = {
    ("jaer2", "davis240"): (
        "-x,-y,z",
        "jAER DAVIS240 files: the IMU's x and y point against the camera's once jAER's y is "
        "flipped to point down (contrast maximization against the gyro on real DAVIS240C pan "
        "and roll recordings)",
    ),
}
"""(format, camera model substring) -> (``--imu-to-camera`` value, where it comes from), for
cameras whose IMU mounting is known. Other cameras' gyros stay in their IMU's axes."""


@dataclass(frozen=True)
class GyroFrame:
    """How a gyro file's samples are taken into the camera frame.

    Attributes:
        rotation: R with ω_camera = R ω_file, or None (used as it is).
        message: what the user should be told (None: nothing to say).
        warning: whether ``message`` is a warning (the frame is unknown) rather than a note.
    """

    rotation: np.ndarray | None
    message: str | None = None
    warning: bool = False


def gyro_frame(gyro_path: str | os.PathLike, imu_to_camera: str | None) -> GyroFrame:
    """The rotation to apply to ``gyro_path``'s samples, and what to say about it.

    ``--imu-to-camera`` wins. Text and HDF5 gyros are in the camera frame by convention. A
    camera file's IMU is in its own axes: its known rotation (:data:`KNOWN_IMU_TO_CAMERA`) is
    applied with a note, otherwise a warning says the gyro stays in IMU axes.
    """
    if imu_to_camera:
        return GyroFrame(imu_rotation(imu_to_camera))
    path = Path(gyro_path)
    kind = detect_format(path)
    if kind not in CAMERA_FORMATS:
        return GyroFrame(None)
    header = CAMERA_FORMATS[kind].read_header(path, kind)
    model = str(header.attrs.get("camera", "")) or kind
    for (fmt, name), (text, source) in KNOWN_IMU_TO_CAMERA.items():
        if fmt == kind and name in model.lower().replace("_", ""):
            return GyroFrame(
                imu_rotation(text),
                f"gyro of a {model} ({kind}) file: applying --imu-to-camera {text} ({source}); "
                "pass --imu-to-camera to override.",
            )
    return GyroFrame(
        None,
        f"the gyro of {path.name} ({model}) is in its IMU's axes and this camera's IMU-to-camera "
        "rotation is not known: it is compared unrotated. Estimate it with `spikegyro "
        "calibrate-imu` and pass --imu-to-camera.",
        warning=True,
    )


def _require_keys(f: h5py.File, keys: tuple[str, ...], path: Path) -> None:
    missing = [k for k in keys if k not in f]
    if missing:
        raise InputError(
            f"{path}: HDF5 file lacks dataset(s) {', '.join(missing)}; expected the official "
            f"layout ({', '.join(OFFICIAL_KEYS)})."
        )


def _hdf5_sensor(f: h5py.File, sensor: tuple[int, int] | None) -> tuple[int, int]:
    if sensor is not None:
        return sensor
    if "width" in f.attrs and "height" in f.attrs:
        return int(f.attrs["width"]), int(f.attrs["height"])
    return DEFAULT_SENSOR


def open_hdf5(path: str | os.PathLike) -> h5py.File:
    """``path`` opened read-only with h5py, or an :class:`InputError` saying it is not HDF5."""
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: not a readable HDF5 file ({exc}).") from None


@reader_boundary
def read_hdf5_attrs(path: str | os.PathLike) -> dict[str, Any]:
    """The attributes of an HDF5 event file as :func:`read_recording` gives them, without
    reading its arrays."""
    with open_hdf5(path) as f:
        return _h5_attrs(f)


def _read_hdf5(path: Path, sensor: tuple[int, int] | None) -> Recording:
    with open_hdf5(path) as f:
        _require_keys(f, ("ev_xy", "ev_ts", "ev_pol"), path)
        xy = f["ev_xy"][()]
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise InputError(f"{path}: ev_xy has shape {xy.shape}; expected (N, 2).")
        width, height = _hdf5_sensor(f, sensor)
        events = EventArray.from_arrays(
            xy[:, 0], xy[:, 1], f["ev_ts"][()], f["ev_pol"][()], width, height, source=str(path)
        )
        gyro = _hdf5_gyro(f, path)
        attrs = _h5_attrs(f)
    return Recording(events=events, gyro=gyro, attrs=attrs)


def _hdf5_gyro(f: h5py.File, path: Path) -> GyroTrace | None:
    if "ang_xyz" not in f and "ang_ts" not in f:
        return None
    _require_keys(f, ("ang_xyz", "ang_ts"), path)
    return GyroTrace.from_arrays(f["ang_ts"][()], f["ang_xyz"][()], source=str(path))


HDF5_INDEX_STRIDE = 4096
""":class:`Hdf5Index` keeps the timestamp of every this many events (16 kB per million)."""


@dataclass(frozen=True)
class Hdf5Index:
    """What reading time spans of an HDF5 event file needs, without its events: every
    :data:`HDF5_INDEX_STRIDE`-th timestamp (µs), the event count, the sensor (width, height),
    the gyro or ground truth and the attributes (see :func:`read_hdf5_span`)."""

    coarse_t: np.ndarray
    count: int
    sensor: tuple[int, int]
    gyro: GyroTrace | None
    attrs: dict[str, Any]


@reader_boundary
def index_hdf5(path: str | os.PathLike) -> Hdf5Index:
    """The :class:`Hdf5Index` of an HDF5 event file (reads the gyro and 1/4096 of the times)."""
    path = Path(path)
    with open_hdf5(path) as f:
        _require_keys(f, ("ev_xy", "ev_ts", "ev_pol"), path)
        ts = f["ev_ts"]
        coarse = ts[::HDF5_INDEX_STRIDE] if ts.shape[0] else np.zeros(0, np.int64)
        return Hdf5Index(coarse, int(ts.shape[0]), _hdf5_sensor(f, None), _hdf5_gyro(f, path),
                         _h5_attrs(f))  # fmt: skip


@reader_boundary
def read_hdf5_span(
    path: str | os.PathLike, t_start_us: int, t_end_us: int, index: Hdf5Index | None = None
) -> EventArray:
    """The events with ``t_start_us <= t < t_end_us`` of an HDF5 event file, reading that part
    of it and at most :data:`HDF5_INDEX_STRIDE` timestamps either side (a 100 ms training window
    of a 500 ms sequence: about a fifth of the file). ``index``: the file's, if at hand."""
    index = index_hdf5(path) if index is None else index
    stride = HDF5_INDEX_STRIDE
    # coarse_t[k] is the time of event k * stride, so the span's first event lies after event
    # (k - 1) * stride, k the first coarse time >= t_start, and its end at or before k' * stride
    lo = max(0, (int(np.searchsorted(index.coarse_t, t_start_us)) - 1) * stride)
    hi = min(index.count, int(np.searchsorted(index.coarse_t, t_end_us)) * stride)
    with open_hdf5(path) as f:
        ts = f["ev_ts"][lo:hi]
        first, end = np.searchsorted(ts, [t_start_us, t_end_us])
        xy = f["ev_xy"][lo + first : lo + end]
        pol = f["ev_pol"][lo + first : lo + end]
    return EventArray.from_arrays(xy[:, 0], xy[:, 1], ts[first:end], pol, *index.sensor,
                                  source=str(path))  # fmt: skip


def _h5_attrs(f: h5py.File) -> dict[str, Any]:
    return {k: _from_h5_attr(v) for k, v in f.attrs.items()}


def _from_h5_attr(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _read_npz(path: Path, sensor: tuple[int, int] | None) -> Recording:
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable .npz file ({exc}).") from None
    with data:
        missing = [k for k in ("x", "y", "t", "p") if k not in data]
        if missing:
            raise InputError(f"{path}: .npz lacks array(s) {', '.join(missing)}; need x, y, t, p.")
        if ("width" in data) != ("height" in data):
            raise InputError(f"{path}: .npz has one of width and height; store both or neither.")
        if ("gyro_t" in data) != ("gyro_omega" in data):
            raise InputError(
                f"{path}: .npz has one of gyro_t and gyro_omega; store both or neither."
            )
        width, height = sensor or (
            (int(data["width"]), int(data["height"])) if "width" in data else DEFAULT_SENSOR
        )
        events = EventArray.from_arrays(
            data["x"], data["y"], data["t"], data["p"], width, height, source=str(path)
        )
        gyro = None
        if "gyro_t" in data:
            gyro = GyroTrace.from_arrays(data["gyro_t"], data["gyro_omega"], source=str(path))
        try:
            attrs = json.loads(str(data["attrs"])) if "attrs" in data else {}
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: .npz attrs is not JSON ({exc.msg}).") from None
    return Recording(events=events, gyro=gyro, attrs=attrs)


def recording_name(path: Path) -> str:
    """A short name for a recording: its folder for ``events.txt`` or an ECD folder, else the
    file's stem."""
    if path.is_dir() or path.name == "events.txt":
        return (path if path.is_dir() else path.parent).name
    return path.stem


@reader_boundary
def read_recording(
    path: str | os.PathLike,
    *,
    sensor: tuple[int, int] | None = None,
    imu_to_camera: np.ndarray | None = None,
) -> Recording:
    """Read a whole event file (any supported format) into memory.

    Args:
        path: the file (or Event Camera Dataset folder, or ROS 2 bag folder).
        sensor: (width, height) in pixels; overrides what the file says. Text formats carry no
            sensor size and default to the DAVIS240's 240x180.
        imu_to_camera: 3x3 rotation R applied to the file's angular velocity, ω_camera =
            R · ω_file (None: as in the file; camera formats record it in the IMU's axes).
    """
    path = Path(path)
    kind = detect_format(path)
    if kind in CAMERA_FORMATS:
        module = CAMERA_FORMATS[kind]
        header = module.read_header(path, kind)
        blocks = module.iter_blocks(path, header)
        return recording_from_blocks(blocks, header, sensor, imu_to_camera, str(path))
    rec = _read_other(path, kind, sensor)
    if rec.gyro is not None and imu_to_camera is not None:
        gyro = replace(rec.gyro, omega=rotate_to_camera(rec.gyro.omega, imu_to_camera))
        rec = replace(rec, gyro=gyro)
    return rec


def _read_other(path: Path, kind: str, sensor: tuple[int, int] | None) -> Recording:
    if kind == "hdf5":
        return _read_hdf5(path, sensor)
    if kind == "npz":
        return _read_npz(path, sensor)
    if kind in ("imu_txt", "gyro_txt"):
        raise InputError(f"{path}: this is a gyro/IMU file, not an event file.")
    events_path = path / "events.txt" if kind == "ecd_dir" else path
    parts = [
        _events_from_rows(rows, sensor or DEFAULT_SENSOR, str(events_path))
        for rows in _iter_text_rows(events_path, 4)
    ]
    events = (
        EventArray.concatenate(parts) if parts else EventArray.empty(*(sensor or DEFAULT_SENSOR))
    )
    events.validate(str(events_path))
    gyro = None
    if kind == "ecd_dir":
        for name, gkind in (("imu.txt", "imu_txt"), ("gyro.txt", "gyro_txt")):
            if (path / name).exists():
                gyro = _read_gyro_text(path / name, gkind)
                break
    return Recording(events=events, gyro=gyro)


@reader_boundary
def iter_event_chunks(
    path: str | os.PathLike,
    *,
    sensor: tuple[int, int] | None = None,
    chunk_events: int = 1_000_000,
) -> Iterator[EventArray]:
    """Stream a file's events in time order, about ``chunk_events`` at a time, in bounded memory.

    HDF5, text and camera files are read incrementally; ``.npz`` is loaded whole (it is not
    streamable). Camera files' packets may be out of time order by up to
    :data:`~spikegyro.events.blocks.REORDER_US`; they are put in order. Ordering across chunk
    boundaries is checked too.
    """
    path = Path(path)
    kind = detect_format(path)
    last_t = np.iinfo(np.int64).min

    def checked(chunk: EventArray) -> EventArray:
        nonlocal last_t
        if len(chunk) and chunk.t[0] < last_t:
            raise InputError(f"{path}: timestamps are not sorted; sort the events by time first.")
        if len(chunk):
            last_t = int(chunk.t[-1])
        return chunk

    if kind == "hdf5":
        with open_hdf5(path) as f:
            _require_keys(f, ("ev_xy", "ev_ts", "ev_pol"), path)
            width, height = _hdf5_sensor(f, sensor)
            n = f["ev_ts"].shape[0]
            for i in range(0, n, chunk_events):
                xy = f["ev_xy"][i : i + chunk_events]
                yield checked(
                    EventArray.from_arrays(
                        xy[:, 0],
                        xy[:, 1],
                        f["ev_ts"][i : i + chunk_events],
                        f["ev_pol"][i : i + chunk_events],
                        width,
                        height,
                        source=str(path),
                    )
                )
    elif kind in ("events_txt", "ecd_dir"):
        events_path = path / "events.txt" if kind == "ecd_dir" else path
        block = max(1 << 16, chunk_events * 32)
        for rows in _iter_text_rows(events_path, 4, block_bytes=block):
            yield checked(_events_from_rows(rows, sensor or DEFAULT_SENSOR, str(events_path)))
    elif kind in CAMERA_FORMATS:
        module = CAMERA_FORMATS[kind]
        header = module.read_header(path, kind)
        blocks = module.iter_blocks(path, header, imu=False)
        size = sensor_of(header, sensor, path)
        for chunk in sorted_chunks(blocks, size, chunk_events, str(path)):
            yield checked(chunk)
    elif kind == "npz":
        events = read_recording(path, sensor=sensor).events
        for i in range(0, len(events), chunk_events):
            yield events[i : i + chunk_events]
    else:
        raise InputError(f"{path}: this is a gyro/IMU file, not an event file.")


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    Readers therefore never see a half-written file, and an interrupted run leaves no debris.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent
    )
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates 0600; give the result the permissions a plain open() would have.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; only if the block succeeds are its files
    moved into ``path`` (created if missing). A failed or interrupted run adds nothing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
        path.mkdir(exist_ok=True)
        for entry in sorted(tmp.iterdir()):
            os.replace(entry, path / entry.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _to_h5_attr(value: Any) -> Any:
    if isinstance(value, dict):
        return json.dumps(value)
    return value


def write_recording(
    path: str | os.PathLike, rec: Recording, *, compression: str | None = None
) -> Path:
    """Write ``rec`` atomically; the format follows the extension (.h5/.hdf5, .npz, .txt, folder).

    HDF5 files use the official layout (readable by the paper's loader) plus ``rec.attrs`` and the
    sensor size as attributes. ``.txt`` writes events only (``t x y p``, seconds); a path without
    a suffix becomes an Event Camera Dataset folder with ``events.txt`` and ``gyro.txt``.
    """
    path = Path(path)
    ev = rec.events
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
            f.create_dataset("ev_xy", data=np.stack([ev.x, ev.y], axis=1), compression=compression)
            f.create_dataset("ev_ts", data=ev.t, compression=compression)
            f.create_dataset("ev_pol", data=ev.p, compression=compression)
            if rec.gyro is not None:
                f.create_dataset("ang_xyz", data=rec.gyro.omega)
                f.create_dataset("ang_ts", data=rec.gyro.t)
            for key, value in rec.attrs.items():
                f.attrs[key] = _to_h5_attr(value)
            f.attrs["width"] = ev.width
            f.attrs["height"] = ev.height
    elif suffix == ".npz":
        arrays: dict[str, Any] = {
            "x": ev.x,
            "y": ev.y,
            "t": ev.t,
            "p": ev.p,
            "width": ev.width,
            "height": ev.height,
            "attrs": json.dumps(rec.attrs),
        }
        if rec.gyro is not None:
            arrays.update(gyro_t=rec.gyro.t, gyro_omega=rec.gyro.omega)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    elif suffix == ".txt":
        _write_events_txt(path, ev)
    elif suffix == "":
        path.mkdir(parents=True, exist_ok=True)
        _write_events_txt(path / "events.txt", ev)
        if rec.gyro is not None:
            write_gyro_txt(path / "gyro.txt", rec.gyro)
    else:
        raise InputError(f"{path}: cannot write '{suffix}'; use .h5, .npz, .txt or a folder.")
    return path


def _write_events_txt(path: Path, ev: EventArray) -> None:
    table = np.column_stack([ev.t / 1e6, ev.x, ev.y, ev.p])
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt=["%.6f", "%d", "%d", "%d"])


def write_gyro_txt(path: str | os.PathLike, gyro: GyroTrace) -> None:
    """Write ``t wx wy wz`` lines (seconds, rad/s) atomically."""
    table = np.column_stack([gyro.t / 1e6, gyro.omega])
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt=["%.6f", "%.9g", "%.9g", "%.9g"])
