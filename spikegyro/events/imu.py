"""Gyro traces from real IMUs: the IMU-to-camera rotation, clock offsets and window means.

A gyro rigidly mounted on a camera measures the camera's angular velocity, but in the IMU's own
axes. With ``R`` the rotation taking IMU axes to camera axes (x right, y down, z forward), the
camera-frame angular velocity is ``omega_cam = R @ omega_imu``. The command-line option
``--imu-to-camera`` gives ``R`` in one of two forms (:func:`imu_rotation`); none of the camera
file formats records it, so the user gives it (the readers take it as ``imu_to_camera=R``):

- an axis permutation with signs, one entry per camera axis: ``"-x,-y,z"`` means
  ``omega_cam = (-gx, -gy, +gz)`` (the DAVIS240C of Rueckauer & Delbruck 2016 with y flipped to
  point down); ``"y,x,-z"`` means ``omega_cam = (gy, gx, -gz)``;
- nine numbers, the rows of ``R`` (comma or space separated): ``"0,1,0, 1,0,0, 0,0,-1"``.

``R`` must be a proper rotation (orthonormal, determinant +1): both frames are right-handed, so a
single flipped axis is a mistake in the option, not a property of the sensor. Angular velocity is
a pseudovector, which is why a reflection cannot be passed through this option.

Clock offset convention (:func:`shift_gyro`): ``offset_us`` is added to the gyro's timestamps,
so a sample stamped ``s`` on the gyro's clock is taken to happen at ``s + offset_us`` on the
events' clock; the reference for an estimate at event time ``t`` is ``gyro(t - offset_us)``.
"""

from __future__ import annotations

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.core import GyroTrace

IMU_TO_CAMERA_HELP = (
    "Rotation from the IMU's axes to the camera's (x right, y down, z forward): signed axes, one "
    "per camera axis, e.g. '-x,-y,z' for omega_cam = (-gx, -gy, gz), or 9 numbers, the rows of "
    "R with omega_cam = R omega_imu. Default: the gyro is already in the camera frame."
)
"""Help text of the ``--imu-to-camera`` option, shared by every command that reads a gyro."""

_AXES = {"x": 0, "y": 1, "z": 2}


def imu_rotation(text: str) -> np.ndarray:
    """The 3x3 rotation ``R`` (omega_cam = R omega_imu) described by ``text``.

    Accepts signed axis names (``"-x,-y,z"``, also ``"-x -y +z"``; each of x, y, z exactly once)
    or nine numbers, the rows of ``R``. Raises :class:`InputError` naming the option when the
    text is neither, or when ``R`` is not a proper rotation (to 1e-3).
    """
    words = text.replace(",", " ").replace(";", " ").split()
    if len(words) == 3 and all(w.lstrip("+-").lower() in _AXES for w in words):
        rotation = np.zeros((3, 3))
        for row, word in enumerate(words):
            rotation[row, _AXES[word.lstrip("+-").lower()]] = -1.0 if word.startswith("-") else 1.0
        if sorted(np.abs(rotation).argmax(axis=1)) != [0, 1, 2]:
            raise InputError(
                f"--imu-to-camera '{text}': each of x, y and z must appear exactly once."
            )
    else:
        try:
            values = [float(w) for w in words]
        except ValueError:
            values = []
        if len(values) != 9:
            raise InputError(
                f"--imu-to-camera '{text}': give signed axes such as '-x,-y,z' or the 9 numbers "
                "of a rotation matrix (row by row)."
            )
        rotation = np.array(values).reshape(3, 3)
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3):
        raise InputError(f"--imu-to-camera '{text}': the matrix is not orthonormal.")
    if np.linalg.det(rotation) < 0:
        raise InputError(
            f"--imu-to-camera '{text}': a reflection (determinant -1); both frames are "
            "right-handed, so flip an even number of axes (or swap two axes and flip one)."
        )
    return rotation


def rotate_to_camera(omega: np.ndarray, rotation: np.ndarray | None) -> np.ndarray:
    """ω (K, 3) rad/s in the IMU's axes -> the camera frame (unchanged if ``rotation`` is None)."""
    return omega if rotation is None else omega @ np.asarray(rotation, dtype=np.float64).T


def rotate_gyro(trace: GyroTrace, rotation: np.ndarray) -> GyroTrace:
    """The trace in the camera frame: every sample becomes ``rotation @ omega`` (rad/s)."""
    return GyroTrace(t=trace.t, omega=rotate_to_camera(trace.omega, rotation))


def shift_gyro(trace: GyroTrace, offset_us: float) -> GyroTrace:
    """The trace on the events' clock: ``offset_us`` (µs, rounded) added to every timestamp."""
    return GyroTrace(t=trace.t + np.int64(round(offset_us)), omega=trace.omega)


def sampling_interval_us(trace: GyroTrace) -> dict[str, float]:
    """Median, minimum and maximum interval between consecutive samples, µs, and the median
    rate in Hz. Raises :class:`InputError` for fewer than two samples."""
    if len(trace) < 2:
        raise InputError("the gyro file holds fewer than two samples; nothing to interpolate.")
    steps = np.diff(trace.t).astype(np.float64)
    median = float(np.median(steps))
    return {
        "median_us": median,
        "min_us": float(steps.min()),
        "max_us": float(steps.max()),
        "rate_hz": 1e6 / median if median > 0 else float("inf"),
    }


def integral(trace: GyroTrace, t_us: np.ndarray) -> np.ndarray:
    """The integral of the linearly interpolated omega from the first sample to ``t_us``, rad.

    Exact for the piecewise-linear interpolant (trapezoids plus a partial trapezoid); shape
    (len(t_us), 3). Only meaningful for times within the trace's span.
    """
    ts = trace.t.astype(np.float64) / 1e6
    w = trace.omega
    cumulative = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(np.diff(ts)[:, None] * (w[1:] + w[:-1]) / 2, axis=0)]
    )
    t = np.asarray(t_us, dtype=np.float64) / 1e6
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, max(len(ts) - 2, 0))
    w_t = trace.interpolate(np.asarray(t_us, dtype=np.float64))
    return cumulative[i] + (t - ts[i])[:, None] * (w[i] + w_t) / 2


def window_means(trace: GyroTrace, starts_us: np.ndarray, ends_us: np.ndarray) -> np.ndarray:
    """Mean omega (rad/s) of the interpolated trace over each ``[start, end]`` (µs), (n, 3).

    A zero-length window gives the interpolated value at its time.
    """
    starts = np.asarray(starts_us, dtype=np.float64)
    ends = np.asarray(ends_us, dtype=np.float64)
    span = (ends - starts)[:, None] / 1e6
    point = trace.interpolate((starts + ends) / 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (integral(trace, ends) - integral(trace, starts)) / span
    return np.where(span > 0, mean, point)


def covers(trace: GyroTrace, t_us: np.ndarray) -> np.ndarray:
    """Whether each time (µs) lies within the trace's first and last sample (bool array)."""
    t = np.asarray(t_us)
    if len(trace) == 0:
        return np.zeros(t.shape, dtype=bool)
    return (t >= trace.t[0]) & (t <= trace.t[-1])
