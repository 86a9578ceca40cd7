"""Rotational camera trajectories: angular velocity ω(t) and orientation R(t), integrated exactly.

Conventions: ``R(t)`` is the camera-to-world rotation ``R_wc`` (a camera-frame vector ``d`` points
along ``R @ d`` in the world). ω is the camera-frame angular velocity, what a gyroscope rigidly
mounted on the camera reads, in rad/s: ``dR/dt = R [ω]×``. ω = (tilt, pan, roll) rates about the
camera's x (right), y (down) and z (forward) axes.

ω(t) is piecewise linear between knots (constant outside them). The orientation is integrated on
a fine grid of ``step_s`` with the SO(3) exponential of ω at each step's midpoint (second-order
Magnus), whose error for these smooth trajectories is far below float precision of the images.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DEG = np.pi / 180.0
TRAJECTORY_KINDS = ("random", "flip")
"""The kinds of :class:`TrajectoryConfig`: the paper's random rotations, or a quadrotor flip."""


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices ``[v]×`` of vectors ``v`` (..., 3) → (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices ``exp([φ]×)`` of rotation vectors ``φ`` (..., 3) in rad (Rodrigues)."""
    phi = np.asarray(phi, dtype=np.float64)
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    k = hat(phi)
    return np.eye(3) + a * k + b * (k @ k)


def so3_log(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) in rad of rotation matrices (..., 3, 3) (angles below π)."""
    r = np.asarray(r, dtype=np.float64)
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    sin = np.sin(theta)
    scale = np.where(
        theta < 1e-6, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(sin == 0, 1, sin))
    )
    return w * scale[..., None]


def _prefix_products(mats: np.ndarray) -> np.ndarray:
    """Running products M_0, M_0 M_1, M_0 M_1 M_2, ... of (n, 3, 3) matrices.

    A Hillis-Steele scan: log2(n) batched matrix products instead of n Python-level ones.
    """
    out = mats.copy()
    shift = 1
    while shift < out.shape[0]:
        out[shift:] = out[:-shift] @ out[shift:]
        shift *= 2
    return out


@dataclass(frozen=True)
class Trajectory:
    """A rotation-only camera motion.

    Attributes:
        t_s: knot times in seconds, increasing, shape (K,).
        omega: angular velocity at the knots, (K, 3) rad/s, camera frame; linear in between,
            constant before the first and after the last knot.
        r0: camera-to-world rotation at t = 0 s, (3, 3).
        duration_s: orientation is tabulated on [0, duration_s] (queries beyond it extrapolate).
        step_s: integration step of the orientation table, seconds.
    """

    t_s: np.ndarray
    omega: np.ndarray
    r0: np.ndarray = field(default_factory=lambda: np.eye(3))
    duration_s: float = 0.5
    step_s: float = 1e-4
    _grid: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = np.atleast_1d(np.asarray(self.t_s, dtype=np.float64))
        w = np.asarray(self.omega, dtype=np.float64).reshape(-1, 3)
        if t.shape[0] != w.shape[0] or t.shape[0] == 0:
            raise ValueError(f"need one ω row per knot time, got {t.shape[0]} and {w.shape[0]}")
        if (np.diff(t) <= 0).any():
            raise ValueError("knot times must be strictly increasing")
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "omega", w)
        object.__setattr__(self, "r0", np.asarray(self.r0, dtype=np.float64))
        n = max(1, int(np.ceil(self.duration_s / self.step_s - 1e-9)))
        h = self.duration_s / n if self.duration_s > 0 else self.step_s
        object.__setattr__(self, "step_s", h)
        mids = (np.arange(n) + 0.5) * h
        grid = np.concatenate([self.r0[None], so3_exp(self.omega_at(mids) * h)])
        object.__setattr__(self, "_grid", _prefix_products(grid))

    @classmethod
    def constant(
        cls, omega: np.ndarray, duration_s: float = 0.5, r0: np.ndarray | None = None
    ) -> Trajectory:
        """Constant angular velocity ``omega`` (3,) rad/s from orientation ``r0`` (default I)."""
        return cls(
            t_s=np.array([0.0]),
            omega=np.asarray(omega, dtype=np.float64).reshape(1, 3),
            r0=np.eye(3) if r0 is None else r0,
            duration_s=duration_s,
        )

    def omega_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Angular velocity at times ``t_s`` (seconds): shape (..., 3), rad/s, camera frame."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.t_s.size == 1:
            return np.broadcast_to(self.omega[0], (*t.shape, 3)).copy()
        return np.stack([np.interp(t, self.t_s, self.omega[:, k]) for k in range(3)], -1)

    def rotation_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Camera-to-world rotations at times ``t_s`` (seconds): shape (..., 3, 3)."""
        t = np.asarray(t_s, dtype=np.float64)
        k = np.clip(np.floor(t / self.step_s), 0, self._grid.shape[0] - 1).astype(np.int64)
        tk = k * self.step_s
        rest = so3_exp(self.omega_at(0.5 * (tk + t)) * (t - tk)[..., None])
        return self._grid[k] @ rest

    def gyro(self, rate_hz: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth at ``rate_hz``: times in µs (int64, 0 .. duration inclusive), ω (K, 3)."""
        n = round(self.duration_s * rate_hz)
        t_us = np.rint(np.arange(n + 1) * (1e6 / rate_hz)).astype(np.int64)
        return t_us, self.omega_at(t_us / 1e6)

    def reversed(self) -> Trajectory:
        """The same path played backwards: ω'(t) = −ω(T − t), starting where this one ends.

        Time-reversing an event stream (t → T − t, polarity flipped) corresponds to this motion.
        The simulated streams match only statistically, not event for event: ESIM sets each
        pixel's reference at the first frame, which differs between the two directions.
        """
        t_end = self.duration_s
        return Trajectory(
            t_s=(t_end - self.t_s)[::-1],
            omega=-self.omega[::-1],
            r0=self.rotation_at(t_end),
            duration_s=t_end,
            step_s=self.step_s,
        )

    def mirrored(self, axis: int) -> Trajectory:
        """The motion seen in a world mirrored across the camera plane normal to ``axis``.

        Mirroring x (``axis=0``, a horizontal image flip) maps ω to (ω_x, −ω_y, −ω_z); mirroring
        y (``axis=1``, a vertical flip) maps it to (−ω_x, ω_y, −ω_z). Use with
        :func:`spikegyro.sim.panorama.mirror_panorama` on the same axis.
        """
        m = np.ones(3)
        m[axis] = -1.0
        return Trajectory(
            t_s=self.t_s,
            omega=-self.omega * m,
            r0=(m[:, None] * self.r0) * m[None, :],
            duration_s=self.duration_s,
            step_s=self.step_s,
        )


@dataclass(frozen=True)
class TrajectoryConfig:
    """Distribution of random rotations (one draw per sequence).

    The initial ω is drawn independently on each axis from the same zero-mean Laplace
    distribution (scale ``omega_scale_deg``): per-axis ω are then uncorrelated and equally spread,
    mean ‖ω‖ ≈ 225 deg/s, with a tail past 800 deg/s (≈0.2% of sequences). The angular
    acceleration is piecewise linear through knots every ``accel_knot_s`` seconds, each
    N(0, ``accel_std_deg``²) per axis, so ω drifts smoothly and slightly within a sequence.

    A share ``slow_share`` of the sequences instead moves like a handheld camera or a robot: the
    initial speed ‖ω‖ is log-uniform in [``slow_min_deg``, ``slow_max_deg``] deg/s about an axis
    drawn uniformly from the sphere (so roll is as likely as tilt and pan), and the acceleration
    knots have a standard deviation of ``slow_accel_per_s`` times that speed per second, so ω
    drifts by about that share of itself in a second. With ``slow_share = 0`` (the default)
    nothing more is drawn, so the paper's sequences stay exactly as they were.

    ``kind = "flip"`` draws a quadrotor's flip instead (:func:`flip_trajectory`): a roll of
    ``flip_deg`` degrees within ``flip_ms`` milliseconds, centred in the sequence, its rate a
    raised cosine peaking at ``2 flip_deg / flip_ms`` (1,200 deg/s for 360 deg in 600 ms), over
    constant tilt and pan rates drawn from N(0, ``flip_drift_deg``²) deg/s (the hover's drift,
    which also makes the scene fire before and after the flip). The other settings are unused.
    """

    omega_scale_deg: float = 107.0
    accel_std_deg: float = 150.0
    accel_knot_s: float = 0.1
    knot_s: float = 5e-4
    slow_share: float = 0.0
    slow_min_deg: float = 5.0
    slow_max_deg: float = 100.0
    slow_accel_per_s: float = 0.5
    kind: str = "random"
    flip_deg: float = 360.0
    flip_ms: float = 600.0
    flip_drift_deg: float = 10.0

    def validate(self) -> None:
        """Raise ValueError naming the first setting out of its range."""
        if self.kind not in TRAJECTORY_KINDS:
            raise ValueError(
                f"trajectory '{self.kind}' must be one of {', '.join(TRAJECTORY_KINDS)}"
            )
        if not (self.flip_ms > 0 and self.flip_deg > 0 and self.flip_drift_deg >= 0):
            raise ValueError(
                f"flip of {self.flip_deg} deg in {self.flip_ms} ms with a drift of "
                f"{self.flip_drift_deg} deg/s: need an angle > 0, a time > 0 and a drift >= 0"
            )
        if not 0.0 <= self.slow_share <= 1.0:
            raise ValueError(f"slow share {self.slow_share} must lie in [0, 1]")
        if not 0.0 < self.slow_min_deg <= self.slow_max_deg:
            raise ValueError(
                f"slow speeds {self.slow_min_deg}-{self.slow_max_deg} deg/s: need 0 < min <= max"
            )
        if min(self.omega_scale_deg, self.accel_std_deg, self.slow_accel_per_s) < 0:
            raise ValueError("angular speed and acceleration scales must not be negative")


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly from SO(3) (from a normalised Gaussian quaternion)."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_trajectory(
    rng: np.random.Generator,
    duration_s: float = 0.5,
    config: TrajectoryConfig | None = None,
    r0: np.ndarray | None = None,
) -> Trajectory:
    """A random rotation of ``duration_s`` seconds drawn from ``config`` (see TrajectoryConfig).

    ``r0`` defaults to a uniformly random start orientation.
    """
    config = config or TrajectoryConfig()
    if config.kind == "flip":
        drift = rng.normal(0.0, config.flip_drift_deg * DEG, size=2)
        r0 = random_rotation(rng) if r0 is None else r0
        return flip_trajectory(duration_s, config, drift, r0)
    n_acc = int(np.ceil(duration_s / config.accel_knot_s)) + 1
    if config.slow_share > 0 and rng.random() < config.slow_share:
        log_lo, log_hi = np.log(config.slow_min_deg), np.log(config.slow_max_deg)
        speed = np.exp(rng.uniform(log_lo, log_hi)) * DEG
        axis = rng.standard_normal(3)
        omega0 = speed * axis / np.linalg.norm(axis)
        acc = rng.normal(0.0, config.slow_accel_per_s * speed, size=(n_acc, 3))
    else:
        omega0 = rng.laplace(0.0, config.omega_scale_deg * DEG, size=3)
        acc = rng.normal(0.0, config.accel_std_deg * DEG, size=(n_acc, 3))
    if r0 is None:
        r0 = random_rotation(rng)
    return _integrated(omega0, np.arange(n_acc) * config.accel_knot_s, acc, r0, duration_s, config)


def _integrated(
    omega0: np.ndarray,
    acc_t: np.ndarray,
    acc: np.ndarray,
    r0: np.ndarray,
    duration_s: float,
    config: TrajectoryConfig,
) -> Trajectory:
    """The trajectory from ``omega0`` (3,) rad/s under an acceleration (rad/s²) linear between
    its knots ``acc_t`` (s), tabulated every ``config.knot_s``."""
    n = max(1, int(np.ceil(duration_s / config.knot_s)))
    t = np.linspace(0.0, duration_s, n + 1)
    # ω = ω0 + ∫α; α is linear between its knots, so the trapezoid rule on a grid that contains
    # them all would be exact; on this fine grid its error is negligible (< 1e-6 rad/s).
    fine = np.union1d(t, acc_t[acc_t <= duration_s])
    alpha = np.stack([np.interp(fine, acc_t, acc[:, k]) for k in range(3)], -1)
    integral = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(0.5 * (alpha[1:] + alpha[:-1]) * np.diff(fine)[:, None], 0)]
    )
    omega = omega0 + np.stack([np.interp(t, fine, integral[:, k]) for k in range(3)], -1)
    return Trajectory(t_s=t, omega=omega, r0=r0, duration_s=duration_s)


def flip_rate(t_s: np.ndarray, flip_deg: float, flip_s: float) -> np.ndarray:
    """Roll rate (rad/s) of a flip of ``flip_deg`` degrees starting at t = 0 and lasting
    ``flip_s`` seconds, at times ``t_s`` (s): the raised cosine
    ``(flip_deg / flip_s) (1 - cos(2 pi t / flip_s))``, 0 outside [0, flip_s]. Its integral is
    ``flip_deg``, its peak twice the mean rate, its acceleration at most ``pi`` times the peak
    rate over ``flip_s``, and rate and acceleration are continuous."""
    t = np.asarray(t_s, dtype=np.float64)
    inside = (t >= 0.0) & (t <= flip_s)
    rate = flip_deg * DEG / flip_s * (1.0 - np.cos(2.0 * np.pi * t / flip_s))
    return np.where(inside, rate, 0.0)


def flip_trajectory(
    duration_s: float,
    config: TrajectoryConfig,
    drift: np.ndarray | None = None,
    r0: np.ndarray | None = None,
) -> Trajectory:
    """A flip (see :class:`TrajectoryConfig`): a roll of ``config.flip_deg`` over
    ``config.flip_ms``, centred in ``duration_s`` seconds, on top of constant tilt and pan
    rates ``drift`` (2,) rad/s (default none), from orientation ``r0`` (default I).

    The knots lie every ``config.knot_s`` (at most) on the flip and on its two ends, and ω is
    linear between knots: the trapezoid rule on a whole period of a cosine over uniform knots is
    exact, so the roll rate integrates to ``flip_deg`` to rounding.
    """
    flip_s = config.flip_ms / 1000.0
    if flip_s > duration_s + 1e-9:
        raise ValueError(f"a flip of {config.flip_ms:g} ms needs a sequence at least that long")
    start = 0.5 * (duration_s - flip_s)
    n = max(8, int(np.ceil(flip_s / config.knot_s)))
    t = start + np.linspace(0.0, flip_s, n + 1)
    t = np.unique(np.concatenate([[0.0], t, [duration_s]]))
    omega = np.zeros((len(t), 3))
    omega[:, :2] = np.zeros(2) if drift is None else np.asarray(drift, dtype=np.float64)
    omega[:, 2] = flip_rate(t - start, config.flip_deg, flip_s)
    return Trajectory(t_s=t, omega=omega, r0=np.eye(3) if r0 is None else r0, duration_s=duration_s)
