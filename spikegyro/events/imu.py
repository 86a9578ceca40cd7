"""The rotation from an IMU's axes to the camera frame (x right, y down, z forward).

A gyro mounted on a camera measures ω in its own axes; spikegyro wants ω in the camera frame.
None of the camera file formats read here records that rotation, so the user gives it, as
``--imu-to-camera``, in one of two spellings:

- an axis string, one entry per camera axis naming the IMU axis (with sign) that points along
  it: ``"-x,-y,z"`` means camera x = −IMU x, camera y = −IMU y, camera z = +IMU z (this is what
  contrast maximization finds for the DAVIS240C of the Rueckauer & Delbruck recordings read
  from jAER files, whose y axis is flipped to point down);
- nine numbers (comma or space separated), the rotation matrix R row by row, with
  ω_camera = R · ω_imu.
"""

from __future__ import annotations

import re

import numpy as np

from spikegyro.errors import InputError

_AXES = {"x": 0, "y": 1, "z": 2}


def imu_rotation(spec: str) -> np.ndarray:
    """The 3x3 rotation R with ω_camera = R · ω_imu, from an axis string or nine numbers.

    Raises :class:`InputError` unless the result is a proper rotation (orthonormal, det +1).
    """
    parts = [s for s in re.split(r"[,\s]+", spec.strip().lower()) if s]
    if len(parts) == 3 and all(re.fullmatch(r"[+-]?[xyz]", s) for s in parts):
        matrix = np.zeros((3, 3))
        for row, part in enumerate(parts):
            matrix[row, _AXES[part[-1]]] = -1.0 if part.startswith("-") else 1.0
    elif len(parts) == 9:
        try:
            matrix = np.array([float(s) for s in parts]).reshape(3, 3)
        except ValueError:
            raise InputError(f"--imu-to-camera '{spec}': nine numbers expected.") from None
    else:
        raise InputError(
            f"--imu-to-camera '{spec}': give three signed IMU axes such as '-x,-y,z' or nine "
            "numbers (the rotation matrix, row by row)."
        )
    if not np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-3) or np.linalg.det(matrix) < 0:
        raise InputError(
            f"--imu-to-camera '{spec}': not a rotation (rows must be orthonormal, determinant "
            "+1); a mirror would turn a right-handed gyro into a left-handed one."
        )
    return matrix


def rotate_to_camera(omega: np.ndarray, rotation: np.ndarray | None) -> np.ndarray:
    """ω (K, 3) rad/s in the IMU's axes -> the camera frame (unchanged if ``rotation`` is None)."""
    return omega if rotation is None else omega @ np.asarray(rotation, dtype=np.float64).T
