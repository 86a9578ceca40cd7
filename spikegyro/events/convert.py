"""Convert any readable event file into any writable one, a chunk at a time, in bounded memory.

Writable (by the output's extension): ``.h5``/``.hdf5`` (the official layout plus attributes),
``.npz``, ``.txt`` (events only, ``t x y p`` in seconds), a path without a suffix (an Event Camera
Dataset folder: ``events.txt`` and ``gyro.txt``, written whole: an existing folder is refused,
or replaced on ``force``), and through the optional ``faery`` package
(extra ``spikegyro[aedat4-write]``): ``.aedat4`` (events and the gyro as an IMU stream),
``.raw`` (Prophesee EVT 3.0) and ``.dat`` (Prophesee DAT 2). The gyro (small: 24 kB per second
at 1 kHz) is read first and held whole, rotated into the camera frame when ``imu_to_camera`` is
given. Each output appears only once complete (:func:`~spikegyro.events.io.atomic_path`).
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.blocks import optional_import
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.events.io import (
    CAMERA_FORMATS,
    DEFAULT_SENSOR,
    _to_h5_attr,
    atomic_path,
    detect_format,
    iter_event_chunks,
    read_gyro_if_any,
    read_recording,
    write_gyro_txt,
)

WRITABLE = (".h5", ".hdf5", ".npz", ".txt", "", ".aedat4", ".raw", ".dat")
Sink = Callable[[EventArray], None]
_AEDAT4_IMU_PACKET = 1024  # the most IMU samples the encoder takes in one packet
_DAT_DTYPE = np.dtype([("t", "=u8"), ("x", "=u2"), ("y", "=u2"), ("payload", "u1")])


def _source_attrs(path: Path, kind: str) -> dict[str, Any]:
    if kind in CAMERA_FORMATS:
        header = CAMERA_FORMATS[kind].read_header(path, kind)
        return dict(header.attrs, source_format=kind)
    if kind == "hdf5":
        with h5py.File(path, "r") as f:
            return {k: v for k, v in f.attrs.items() if k not in ("width", "height")}
    return {}


@contextmanager
def _hdf5_sink(
    path: Path, sensor: tuple[int, int], gyro: GyroTrace | None, attrs: dict[str, Any]
) -> Iterator[Sink]:
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        xy = f.create_dataset("ev_xy", (0, 2), dtype=np.int16, maxshape=(None, 2), chunks=True)
        ts = f.create_dataset("ev_ts", (0,), dtype=np.int64, maxshape=(None,), chunks=True)
        pol = f.create_dataset("ev_pol", (0,), dtype=np.uint8, maxshape=(None,), chunks=True)

        def write(ev: EventArray) -> None:
            n0, n1 = ts.shape[0], ts.shape[0] + len(ev)
            for ds in (xy, ts, pol):
                ds.resize(n1, axis=0)
            xy[n0:n1] = np.stack([ev.x, ev.y], axis=1)
            ts[n0:n1] = ev.t
            pol[n0:n1] = ev.p

        yield write
        if gyro is not None:
            f.create_dataset("ang_xyz", data=gyro.omega)
            f.create_dataset("ang_ts", data=gyro.t)
        for key, value in attrs.items():
            f.attrs[key] = _to_h5_attr(value)
        f.attrs["width"], f.attrs["height"] = sensor


def _npy_entry(zf: zipfile.ZipFile, name: str, raw: Path, dtype: np.dtype, n: int) -> None:
    with zf.open(f"{name}.npy", "w", force_zip64=True) as out:
        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False}
        np.lib.format.write_array_header_2_0(out, dict(header, shape=(n,)))
        with open(raw, "rb") as src:
            shutil.copyfileobj(src, out, 1 << 18)


@contextmanager
def _npz_sink(
    path: Path, sensor: tuple[int, int], gyro: GyroTrace | None, attrs: dict[str, Any]
) -> Iterator[Sink]:
    # A .npy header needs the length first: stream each column to a raw file, then zip them.
    dtypes = {"x": np.dtype(np.int16), "y": np.dtype(np.int16), "t": np.dtype(np.int64)}
    dtypes["p"] = np.dtype(np.uint8)
    count = 0
    with tempfile.TemporaryDirectory(dir=path.parent) as scratch, ExitStack() as stack:
        files = {k: stack.enter_context(open(Path(scratch) / k, "wb")) for k in dtypes}

        def write(ev: EventArray) -> None:
            nonlocal count
            for key, f in files.items():
                f.write(getattr(ev, key).astype(dtypes[key], copy=False).tobytes())
            count += len(ev)

        yield write
        stack.close()
        small: dict[str, Any] = {"width": sensor[0], "height": sensor[1]}
        small["attrs"] = json.dumps({k: _to_h5_attr(v) for k, v in attrs.items()}, default=str)
        if gyro is not None:
            small.update(gyro_t=gyro.t, gyro_omega=gyro.omega)
        with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for key, dtype in dtypes.items():
                _npy_entry(zf, key, Path(scratch) / key, dtype, count)
            for key, value in small.items():
                with zf.open(f"{key}.npy", "w") as out:
                    np.lib.format.write_array(out, np.asarray(value))


@contextmanager
def _events_txt_sink(path: Path) -> Iterator[Sink]:
    with atomic_path(path) as tmp, open(tmp, "w") as f:

        def write(ev: EventArray) -> None:
            table = np.column_stack([ev.t / 1e6, ev.x, ev.y, ev.p])
            np.savetxt(f, table, fmt=["%.6f", "%d", "%d", "%d"])

        yield write


@contextmanager
def _replaced_folder(path: Path) -> Iterator[Path]:
    """Yield a scratch folder beside ``path``; once the block succeeds, it replaces ``path``
    whole (an older folder there is removed), so no mix of old and new files is ever left."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    old = tmp.with_name(tmp.name + ".old")
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; give mkdir's permissions
        if path.exists():
            os.replace(path, old)
        os.replace(tmp, path)
    finally:
        for scratch in (tmp, old):
            if scratch.exists():
                shutil.rmtree(scratch)


@contextmanager
def _text_sink(path: Path, gyro: GyroTrace | None) -> Iterator[Sink]:
    if path.suffix:
        with _events_txt_sink(path) as write:
            yield write
        return
    with _replaced_folder(path) as folder, _events_txt_sink(folder / "events.txt") as write:
        yield write
        if gyro is not None:
            write_gyro_txt(folder / "gyro.txt", gyro)


def _check_folder_output(src: Path, dst: Path, force: bool) -> None:
    """An existing output folder is replaced whole, and only on ``force``."""
    if not dst.exists():
        return
    if not dst.is_dir():
        raise InputError(f"{dst}: exists and is not a folder; give a new path for the folder.")
    names = sorted(p.name for p in dst.iterdir())
    if names and not force:
        shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
        raise InputError(
            f"{dst}: the folder already holds {shown}; writing events.txt and gyro.txt there "
            "would leave a mix of old and new files: give a new folder, or --force to replace "
            "it whole."
        )
    if names and src.resolve().is_relative_to(dst.resolve()):
        raise InputError(f"{dst}: the folder holds the input {src}; give another output folder.")


def _faery_events(ev: EventArray, faery: Any) -> np.ndarray:
    out = np.empty(len(ev), dtype=faery.EVENTS_DTYPE)
    out["t"], out["x"], out["y"], out["on"] = ev.t, ev.x, ev.y, ev.p.astype(bool)
    return out


def _check_faery_times(ev: EventArray, path: Path) -> None:
    if len(ev) and ev.t[0] < 0:
        raise InputError(f"{path}: camera formats cannot hold negative timestamps ({ev.t[0]} us).")


@contextmanager
def _faery_sink(
    path: Path, sensor: tuple[int, int], gyro: GyroTrace | None, attrs: dict[str, Any]
) -> Iterator[Sink]:
    faery = optional_import("faery", "aedat4-write", path)
    ext = faery.extension
    suffix = path.suffix.lower()
    with ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(path))
        if suffix == ".aedat4":
            encoder = stack.enter_context(
                ext.aedat.Encoder(
                    str(tmp), _aedat4_description(ext.aedat, sensor, gyro), ext.aedat.LZ4_DEFAULT
                )
            )
        elif suffix == ".raw":
            encoder = stack.enter_context(ext.evt.Encoder(str(tmp), "evt3", False, sensor, True))
        else:
            encoder = stack.enter_context(ext.dat.Encoder(str(tmp), "dat2", "cd", False, sensor))

        def write(ev: EventArray) -> None:
            _check_faery_times(ev, path)
            if not len(ev):
                return
            packet = _faery_events(ev, faery)
            if suffix == ".aedat4":
                encoder.write(0, packet)
            elif suffix == ".raw":
                encoder.write({"events": packet})
            else:
                dat = np.empty(len(ev), _DAT_DTYPE)
                dat["t"], dat["x"], dat["y"], dat["payload"] = ev.t, ev.x, ev.y, ev.p
                encoder.write(dat)

        yield write
        if suffix == ".aedat4" and gyro is not None:
            imus = _aedat4_imus(gyro)
            for i in range(0, len(imus), _AEDAT4_IMU_PACKET):
                encoder.write(1, imus[i : i + _AEDAT4_IMU_PACKET])


def _aedat4_imus(gyro: GyroTrace) -> np.ndarray:
    sensors = ("accelerometer", "gyroscope", "magnetometer")
    names = ["temperature", *(f"{s}_{a}" for s in sensors for a in "xyz")]
    imus = np.zeros(len(gyro), dtype=[("t", "<u8"), *((n, "<f4") for n in names)])
    imus["t"] = gyro.t
    for k, axis in enumerate("xyz"):
        imus[f"gyroscope_{axis}"] = np.degrees(gyro.omega[:, k])  # DV records deg/s
    return imus


def _aedat4_description(aedat: Any, sensor: tuple[int, int], gyro: GyroTrace | None) -> list:
    def attr(kind: str, value: Any) -> Any:
        return aedat.DescriptionAttribute(kind, value)

    def stream(sid: int, name: str, type_id: str, info: dict[str, Any]) -> Any:
        path = f"/mainloop/Recorder/outInfo/{sid}/"
        attrs = {
            "compression": attr("string", "LZ4"),
            "originalOutputName": attr("string", name),
            "typeIdentifier": attr("string", type_id),
        }
        info_node = aedat.DescriptionNode("info", f"{path}info/", info, [])
        return aedat.DescriptionNode(str(sid), path, attrs, [info_node])

    source = attr("string", "spikegyro")
    size = {"sizeX": attr("int", sensor[0]), "sizeY": attr("int", sensor[1])}
    streams = [stream(0, "events", "EVTS", dict(size, source=source))]
    if gyro is not None:
        streams.append(stream(1, "imu", "IMUS", {"source": source}))
    return [aedat.DescriptionNode("outInfo", "/mainloop/Recorder/outInfo/", {}, streams)]


def _open_sink(
    path: Path, sensor: tuple[int, int], gyro: GyroTrace | None, attrs: dict[str, Any]
) -> Any:
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return _hdf5_sink(path, sensor, gyro, attrs)
    if suffix == ".npz":
        return _npz_sink(path, sensor, gyro, attrs)
    if suffix in (".txt", ""):
        return _text_sink(path, gyro)
    if suffix in (".aedat4", ".raw", ".dat"):
        return _faery_sink(path, sensor, gyro, attrs)
    raise InputError(
        f"{path}: cannot write '{suffix}'; write .h5, .npz, .txt, a folder, .aedat4, .raw or .dat."
    )


def convert(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    sensor: tuple[int, int] | None = None,
    imu_to_camera: np.ndarray | None = None,
    chunk_events: int = 1_000_000,
    progress: Callable[[int], None] | None = None,
    force: bool = False,
) -> tuple[int, int]:
    """Copy the events (and gyro) of ``src`` into ``dst``; returns (events, gyro samples).

    ``progress`` is called with the number of events written after each chunk. An output
    folder that exists and is not empty is refused, or replaced whole when ``force`` is given.
    """
    src, dst = Path(src), Path(dst)
    if dst.suffix.lower() not in WRITABLE:
        _open_sink(dst, DEFAULT_SENSOR, None, {})  # raises the one-line error
    kind = detect_format(src)
    if src.resolve() == dst.resolve():
        raise InputError(f"{dst}: the output would overwrite the input.")
    if dst.suffix == "":
        _check_folder_output(src, dst, force)
    gyro = read_gyro_if_any(src, imu_to_camera=imu_to_camera)
    chunks = iter_event_chunks(src, sensor=sensor, chunk_events=chunk_events)
    first = next(chunks, None)
    # An empty source still names its sensor; reading it whole costs nothing then.
    empty = first is None
    size = read_recording(src, sensor=sensor).events.sensor_size if empty else first.sensor_size
    n = 0
    with _open_sink(dst, size, gyro, _source_attrs(src, kind)) as write:
        for chunk in itertools.chain([first] if first is not None else [], chunks):
            write(chunk)
            n += len(chunk)
            if progress is not None:
                progress(n)
    return n, 0 if gyro is None else len(gyro)
