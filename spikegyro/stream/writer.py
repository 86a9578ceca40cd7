"""Angular-velocity prediction files: CSV or HDF5 (by extension), written in blocks, atomically.

Columns / datasets (angular velocity in rad/s, camera frame):

- CSV: header ``t,wx,wy,wz`` (t in seconds, microsecond precision); with a gyro reference also
  ``gyro_wx,gyro_wy,gyro_wz,err`` where ``err`` is the Euclidean error in rad/s.
- HDF5: ``t_us`` (K,) int64 microseconds, ``omega`` (K, 3) float32 rad/s; with a gyro reference
  also ``gyro_omega`` (K, 3). The layout mirrors the official ``ang_ts`` / ``ang_xyz`` pair.

Estimators that report their confidence (contrast maximization) add, per estimate:
``events`` (events in its window), ``window_ms`` (the window's span), ``contrast_gain`` (its
contrast over that of ω = 0; near 1: no structure found) and ``ill_posed`` (bits: 1 too few
events, 2 too little motion to tell from none); as CSV columns after the others, as HDF5
datasets of those names.

The spiking network on the event clock writes a row per millisecond holding its latest step's
estimate, with ``events`` (the step's events), ``step_ms`` (the step's length) and ``age_ms``
(how long before the row that step ended): the estimate's latency.

The path ``-`` writes the CSV to standard output instead, flushed after each block, for a
program reading the estimates as they come.

A CSV prediction file without confidence or gyro columns reads back with
:func:`spikegyro.events.io.read_gyro`; any reads back with :func:`read_predictions`.
"""

from __future__ import annotations

import os
import sys
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any

import h5py
import numpy as np

from spikegyro.checks import check_output_file
from spikegyro.errors import InputError
from spikegyro.events.io import atomic_path

_CSV_SUFFIXES = (".csv", ".txt")
CONFIDENCE_COLUMNS = ("events", "window_ms", "contrast_gain", "ill_posed")
STEP_COLUMNS = ("events", "step_ms", "age_ms")
_FORMATS = {"events": "%d", "window_ms": "%.3f", "contrast_gain": "%.5f", "ill_posed": "%d",
            "step_ms": "%.3f", "age_ms": "%.3f"}  # fmt: skip
_H5_SUFFIXES = (".h5", ".hdf5")


STDOUT = "-"
"""The ``--out`` that writes CSV to standard output."""


def check_prediction_path(path: str | os.PathLike) -> Path:
    """Raise :class:`InputError` unless ``path`` has a supported extension (.csv/.txt/.h5/.hdf5)
    or is ``-`` (standard output)."""
    if str(path) == STDOUT:
        return Path(STDOUT)
    return check_output_file(path, "--out", _CSV_SUFFIXES + _H5_SUFFIXES)


class PredictionWriter:
    """Append predictions block by block; the file appears (atomically) only on a clean close.

    Use as a context manager::

        with PredictionWriter("pred.csv", with_gyro=True) as w:
            w.append(t_us, omega, gyro_omega)
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        with_gyro: bool = False,
        with_confidence: bool = False,
        with_steps: bool = False,
    ) -> None:
        self.path = check_prediction_path(path)
        self.with_gyro = with_gyro
        self.with_confidence = with_confidence or with_steps
        self.columns = STEP_COLUMNS if with_steps else CONFIDENCE_COLUMNS if with_confidence else ()
        self.rows = 0
        self._stack = ExitStack()
        self._csv = None
        self._h5: h5py.File | None = None

    def __enter__(self) -> PredictionWriter:
        if str(self.path) == STDOUT:
            self._csv = sys.stdout
            self._write_header()
            return self
        tmp = self._stack.enter_context(atomic_path(self.path))
        if self.path.suffix.lower() in _H5_SUFFIXES:
            self._h5 = self._stack.enter_context(h5py.File(tmp, "w"))
            self._h5.create_dataset(
                "t_us", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(65536,)
            )
            for name in ("omega", "gyro_omega") if self.with_gyro else ("omega",):
                self._h5.create_dataset(
                    name, shape=(0, 3), maxshape=(None, 3), dtype=np.float32, chunks=(65536, 3)
                )
            self._h5["omega"].attrs["units"] = "rad/s"
            self._h5["t_us"].attrs["units"] = "us"
            for name in self.columns:
                self._h5.create_dataset(
                    name, shape=(0,), maxshape=(None,), dtype=np.float32, chunks=(65536,)
                )
        else:
            self._csv = self._stack.enter_context(open(tmp, "w", newline=""))
            self._write_header()
        return self

    def _write_header(self) -> None:
        header = "t,wx,wy,wz" + (",gyro_wx,gyro_wy,gyro_wz,err" if self.with_gyro else "")
        header += "".join(f",{c}" for c in self.columns)
        self._csv.write(header + "\n")
        self._csv.flush()

    def append(
        self,
        t_us: np.ndarray,
        omega: np.ndarray,
        gyro_omega: np.ndarray | None = None,
        confidence: Any = None,
    ) -> None:
        """Add rows: times (µs), predicted ω (K, 3) rad/s and, if enabled, the gyro's ω (K, 3)
        and the confidence or steps (an ``Estimates``: events, window_us, delay_us,
        contrast_gain, ill_posed)."""
        t_us = np.asarray(t_us, dtype=np.int64)
        omega = np.asarray(omega, dtype=np.float64).reshape(-1, 3)
        if self.with_gyro != (gyro_omega is not None):
            raise ValueError("gyro_omega must be given exactly when the writer has with_gyro")
        if self.with_confidence != (confidence is not None):
            raise ValueError("confidence must be given exactly when the writer has it")
        extra = {} if confidence is None else _extra_columns(confidence, self.columns)
        if self._h5 is not None:
            blocks = {"t_us": t_us, "omega": omega, **extra}
            if gyro_omega is not None:
                blocks["gyro_omega"] = gyro_omega
            for name, block in blocks.items():
                ds = self._h5[name]
                ds.resize(self.rows + len(t_us), axis=0)
                ds[self.rows :] = block
        else:
            columns = [t_us[:, None] / 1e6, omega]
            fmt = ["%.6f", "%.7g", "%.7g", "%.7g"]
            if gyro_omega is not None:
                gyro_omega = np.asarray(gyro_omega, dtype=np.float64).reshape(-1, 3)
                err = np.linalg.norm(omega - gyro_omega, axis=1)
                columns += [gyro_omega, err[:, None]]
                fmt += ["%.7g"] * 4
            columns += [extra[name][:, None] for name in self.columns]
            fmt += [_FORMATS[name] for name in self.columns]
            np.savetxt(self._csv, np.hstack(columns), fmt=fmt, delimiter=",")
            self._csv.flush()
        self.rows += len(t_us)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stack.__exit__(exc_type, exc, tb)


def _extra_columns(est: Any, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The columns ``names`` of an ``Estimates`` block (float64, times in ms)."""
    every = {
        "events": est.events,
        "window_ms": np.asarray(est.window_us, dtype=np.float64) / 1000.0,
        "step_ms": np.asarray(est.window_us, dtype=np.float64) / 1000.0,
        "age_ms": np.asarray(est.delay_us, dtype=np.float64) / 1000.0,
        "contrast_gain": est.contrast_gain,
        "ill_posed": est.ill_posed,
    }
    return {name: np.asarray(every[name], dtype=np.float64) for name in names}


def write_predictions(
    path: str | os.PathLike,
    t_us: np.ndarray,
    omega: np.ndarray,
    gyro: np.ndarray | None = None,
) -> Path:
    """Write a whole prediction series at once (CSV or HDF5 by extension, atomically).

    Args:
        path: output file, ``.csv``/``.txt`` or ``.h5``/``.hdf5``.
        t_us: (K,) prediction times, microseconds.
        omega: (K, 3) predicted angular velocity, rad/s.
        gyro: optional (K, 3) reference angular velocity at the same times, rad/s.
    """
    with PredictionWriter(path, with_gyro=gyro is not None) as writer:
        writer.append(t_us, omega, gyro)
    return writer.path


def read_predictions(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a prediction file back: ``t_us``, ``omega`` and, when present, ``gyro_omega``."""
    path = check_prediction_path(path)
    if not path.exists():
        raise InputError(f"{path}: no such prediction file.")
    extra = tuple(dict.fromkeys(CONFIDENCE_COLUMNS + STEP_COLUMNS))
    names = ("t_us", "omega", "gyro_omega", *extra)
    if path.suffix.lower() in _H5_SUFFIXES:
        with h5py.File(path, "r") as f:
            return {k: f[k][()] for k in names if k in f}
    with open(path) as f:
        header = f.readline().strip().split(",")
        has_rows = bool(f.readline().strip())
    table = (
        np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        if has_rows
        else np.zeros((0, len(header)))
    )
    out = {"t_us": np.rint(table[:, 0] * 1e6).astype(np.int64), "omega": table[:, 1:4]}
    if "gyro_wx" in header:
        i = header.index("gyro_wx")
        out["gyro_omega"] = table[:, i : i + 3]
    for name in extra:
        if name in header:
            out[name] = table[:, header.index(name)]
    return out
