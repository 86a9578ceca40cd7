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

import math
from dataclasses import dataclass

import numpy as np

from spikegyro.errors import InputError
from spikegyro.events.core import GyroTrace

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


def rotation_text(rotation: np.ndarray, tolerance_deg: float = 5.0) -> str:
    """``--imu-to-camera`` text for R: signed axes (``"-x,-y,z"``) when R is within
    ``tolerance_deg`` of a signed permutation, else its 9 numbers row by row."""
    r = np.asarray(rotation, dtype=np.float64)
    axes = np.abs(r).argmax(axis=1)
    perm = np.zeros((3, 3))
    perm[np.arange(3), axes] = np.sign(r[np.arange(3), axes])
    if sorted(axes) == [0, 1, 2] and np.linalg.det(perm) > 0:
        cos = np.clip((np.trace(perm.T @ r) - 1) / 2, -1.0, 1.0)
        if np.degrees(np.arccos(cos)) <= tolerance_deg:
            names = "xyz"
            return ",".join(
                ("-" if perm[i, axes[i]] < 0 else "") + names[axes[i]] for i in range(3)
            )
    return ",".join(f"{v:.4f}" for v in r.ravel())


@dataclass(frozen=True)
class ImuFit:
    """The gyro's frame, bias and clock offset fitted to camera-frame angular velocities.

    The model: ``ω_camera(t) = R (g(t - offset) - bias)`` for gyro samples ``g`` in the IMU's
    axes (see :func:`shift_gyro` for the offset's sign).

    Attributes:
        rotation: R (3, 3), ω_camera = R ω_imu.
        bias: (3,) rad/s, in the IMU's axes (subtract from the raw gyro).
        offset_us: added to the gyro's timestamps to put them on the events' clock.
        rms_rad_s: RMS residual per sample (Euclidean), rad/s.
        samples: estimates used.
        spread_rad_s: (3,) singular values of the gyro's centred samples / sqrt(samples):
            how much the motion spans each direction (the rotation is only determined about
            directions that were excited).
    """

    rotation: np.ndarray
    bias: np.ndarray
    offset_us: float
    rms_rad_s: float
    samples: int
    spread_rad_s: np.ndarray


def _fit_rotation_bias(
    omega_cam: np.ndarray, g: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Least-squares R in SO(3) and bias b with ω_cam ≈ R (g - b) (centred Kabsch); returns
    (R, b, RMS residual, singular values of the centred g / sqrt(n))."""
    mean_c, mean_g = omega_cam.mean(axis=0), g.mean(axis=0)
    c, gc = omega_cam - mean_c, g - mean_g
    u, _, vt = np.linalg.svd(gc.T @ c)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    bias = mean_g - rotation.T @ mean_c
    residual = omega_cam - (g - bias) @ rotation.T
    rms = float(np.sqrt((residual**2).sum(axis=1).mean()))
    spread = np.linalg.svd(gc, compute_uv=False) / math.sqrt(len(g))
    return rotation, bias, rms, spread


def fit_imu_to_camera(
    t_us: np.ndarray,
    omega_cam: np.ndarray,
    gyro: GyroTrace,
    max_offset_us: float = 50_000.0,
    step_us: float = 1000.0,
) -> ImuFit:
    """Fit the IMU-to-camera rotation, the gyro's bias and the clock offset (see :class:`ImuFit`).

    Args:
        t_us: times of camera-frame estimates ω (e.g. contrast maximization's), µs.
        omega_cam: (K, 3) those estimates, rad/s.
        gyro: the raw gyro, in its IMU's axes.
        max_offset_us, step_us: offsets tried, ``-max..max`` every ``step_us``; the best is
            refined by a parabola through its neighbours.

    Raises :class:`InputError` when fewer than 10 estimates overlap the gyro.
    """
    t = np.asarray(t_us, dtype=np.float64)
    omega_cam = np.asarray(omega_cam, dtype=np.float64)

    def fit(offset: float) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, int]:
        shifted = t - offset
        inside = (shifted >= gyro.t[0]) & (shifted <= gyro.t[-1])
        if inside.sum() < 10:
            return np.eye(3), np.zeros(3), math.inf, np.zeros(3), int(inside.sum())
        g = gyro.interpolate(shifted[inside])
        return (*_fit_rotation_bias(omega_cam[inside], g), int(inside.sum()))

    offsets = np.arange(-max_offset_us, max_offset_us + step_us / 2, step_us)
    costs = np.array([fit(o)[2] for o in offsets])
    if not np.isfinite(costs).any():
        raise InputError(
            "fewer than 10 estimates overlap the gyro's time span; check that the gyro belongs "
            "to this recording (same clock)."
        )
    best = int(np.argmin(costs))
    offset = float(offsets[best])
    if 0 < best < len(offsets) - 1 and np.isfinite(costs[best - 1 : best + 2]).all():
        a, b, c = (costs[best - 1 : best + 2] ** 2).tolist()  # squared: a parabola near the min
        curvature = a - 2 * b + c
        if curvature > 0:
            offset += 0.5 * step_us * (a - c) / curvature
    rotation, bias, rms, spread, n = fit(offset)
    return ImuFit(rotation, bias, offset, rms, n, spread)
