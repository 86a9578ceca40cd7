"""The mean predictor: always answer the training split's mean angular velocity.

The paper's naive baseline ("arithmetic mean of the training dataset, which is close to zero").
Any model must beat it; its median relative error is about 1 because the mean is nearly zero.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.io import read_gyro

_SEQUENCE_SUFFIXES = (".h5", ".hdf5", ".npz")


def training_mean_omega(data_dir: str | os.PathLike, split: str = "train") -> np.ndarray:
    """Mean ground-truth angular velocity (3,) in rad/s over every gyro sample of ``split``.

    Each sample counts once (longer sequences weigh more). Reads only the ``ang_xyz`` dataset of
    HDF5 sequence files, so the events are never loaded.

    Raises:
        InputError: if ``data_dir/split`` is missing or holds no ground truth.
    """
    folder = Path(data_dir) / split
    files = sorted(f for f in folder.glob("*") if f.suffix.lower() in _SEQUENCE_SUFFIXES)
    if not files:
        raise InputError(
            f"{folder}: no sequence files (.h5/.npz) to take the mean predictor's training mean "
            "from; generate the split with `spikegyro simulate` or pass another --data folder."
        )
    total = np.zeros(3)
    count = 0
    for path in files:
        omega = _ground_truth(path)
        total += omega.sum(axis=0)
        count += omega.shape[0]
    if count == 0:
        raise InputError(f"{folder}: the sequence files hold no angular-velocity samples.")
    return total / count


def _ground_truth(path: Path) -> np.ndarray:
    if path.suffix.lower() in (".h5", ".hdf5"):
        with h5py.File(path, "r") as f:
            if "ang_xyz" not in f:
                raise InputError(f"{path}: no 'ang_xyz' dataset (ground-truth angular velocity).")
            return np.asarray(f["ang_xyz"], dtype=np.float64).reshape(-1, 3)
    return read_gyro(path).omega


def mean_predictions(mean_omega: np.ndarray, num_windows: int, num_steps: int) -> np.ndarray:
    """The constant prediction ``mean_omega`` (rad/s) as an (num_windows, num_steps, 3) array."""
    mean_omega = np.asarray(mean_omega, dtype=np.float64).reshape(1, 1, 3)
    return np.broadcast_to(mean_omega, (num_windows, num_steps, 3)).copy()
