"""Image of warped events (IWE) and its contrast, with the exact gradient, compiled with Numba.

An event with camera-frame ray ``b = (x, y, 1)`` (undistorted, normalised) fired ``dt`` seconds
before the reference time is rotated to ``r = exp([φ]x) b`` with ``φ = -ω dt`` (ω in rad/s, as a
camera-mounted gyro reads it: a static direction seen from a camera turning at ω moves as
``db/dt = -ω x b``) and projected with the pinhole ``u = fx r_x / r_z + cx``. Events vote
bilinearly into the IWE ``H``, which is blurred with a Gaussian ``G`` into ``I = G * H``; the
contrast is the variance of ``I`` over its pixels.

Gradient. ``d var / dω = (2/P) Σ_p (I_p - μ) dI_p/dω``; since ``G`` is symmetric this equals
``(2/P) Σ_q Q_q dH_q/dω`` with ``Q = G * (I - μ)``, so each event adds the derivative of its
bilinear weights times ``Q`` at its four pixels. The ray's derivative is exact for any rotation
angle: with the left Jacobian ``J(φ) = I + b [φ]x + c [φ]x²`` of SO(3),
``exp([φ + δφ]x) ≈ exp([J(φ) δφ]x) exp([φ]x)``, hence ``dr/dω = dt [r]x J(φ)``.
"""

from __future__ import annotations

import functools
import math
import threading

import numba
import numpy as np


@functools.lru_cache(maxsize=64)
def gaussian_taps(sigma: float) -> np.ndarray:
    """Normalised 1-D Gaussian taps to 3σ (σ in pixels); ``[1.0]`` when σ <= 0. Cached (each
    objective call asks for them): read-only."""
    if sigma <= 0:
        taps = np.ones(1)
    else:
        radius = math.ceil(3.0 * sigma)
        taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
        taps /= taps.sum()
    taps.flags.writeable = False
    return taps


@numba.njit(cache=True, nogil=True, fastmath=True)
def _rotation_coefficients(theta2: float) -> tuple[float, float, float]:
    """sin θ/θ, (1 - cos θ)/θ², (θ - sin θ)/θ³ from θ².

    Below θ = 0.5 rad (every event of a real window) their Taylor series
    (:func:`_taylor_coefficients`), much cheaper than sqrt, sin and cos per event.
    """
    if theta2 < SMALL_ANGLE2:
        return _taylor_coefficients(theta2)
    theta = math.sqrt(theta2)
    s = math.sin(theta)
    return s / theta, (1.0 - math.cos(theta)) / theta2, (theta - s) / (theta2 * theta)


SMALL_ANGLE2 = 0.25
"""θ² (rad²) below which :func:`_taylor_coefficients` is exact to 1e-8."""


@numba.njit(cache=True, nogil=True, fastmath=True, inline="always")
def _taylor_coefficients(theta2: float) -> tuple[float, float, float]:
    """:func:`_rotation_coefficients` by their Taylor series to θ⁶: for θ² < ``SMALL_ANGLE2``.
    Branch-free, so that a loop over events that calls it vectorizes."""
    t4 = theta2 * theta2
    return (
        1.0 - theta2 / 6.0 + t4 / 120.0 - t4 * theta2 / 5040.0,
        0.5 - theta2 / 24.0 + t4 / 720.0 - t4 * theta2 / 40320.0,
        1.0 / 6.0 - theta2 / 120.0 + t4 / 5040.0 - t4 * theta2 / 362880.0,
    )


@numba.njit(cache=True, nogil=True, fastmath=True)
def _blur_into(image: np.ndarray, taps: np.ndarray, out: np.ndarray, row: np.ndarray) -> None:
    """Blur (H, W) ``image`` into ``out`` (another array) with zero padding; ``row``: scratch of
    W + len(taps) - 1 values.

    Row by row, the y pass adds each tap's source row into ``row``, padded by the radius on
    both sides, and the x pass adds each tap's shift of ``row`` into the output row. Every
    innermost loop runs along x over contiguous memory with no bounds test, so both
    vectorize, where an x pass that sums the taps per pixel in a register does not; on a
    240x180 image the blur is much of the objective's cost.
    """
    height, width = image.shape
    radius = (taps.shape[0] - 1) // 2
    for y in range(height):
        target = out[y]
        if radius == 0:
            for x in range(width):
                target[x] = taps[0] * image[y, x]
            continue
        row[:] = 0.0
        line = row[radius : radius + width]
        for k in range(max(-radius, -y), min(radius, height - 1 - y) + 1):
            w = taps[k + radius]
            source = image[y + k]
            for x in range(width):
                line[x] += w * source[x]
        target[:] = 0.0
        for k in range(2 * radius + 1):
            w = taps[k]
            for x in range(width):
                target[x] += w * row[x + k]


@numba.njit(cache=True, nogil=True, fastmath=True, inline="always")
def _project(
    a: float,
    b: float,
    c: float,
    theta2: float,
    px: float,
    py: float,
    pz: float,
    x: float,
    y: float,
    intrinsics: np.ndarray,
    inv: float,
    with_gradient: bool,
) -> tuple[float, float, bool, float, float, float, float, float, float]:
    """Ray ``(x, y, 1)`` rotated by the rotation vector φ = (px, py, pz) and projected, given
    θ² = |φ|² and φ's :func:`_rotation_coefficients` ``a, b, c``.

    Returns ``(u, v, valid)`` and, with ``with_gradient``, ``-du/dφ`` and ``-dv/dφ`` (px per
    rad, 3 values each; zeros without). Scalars only: no per-event arrays.
    """
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    # p x b and p x (p x b) for the ray b = (x, y, 1)
    k0, k1, k2 = py - pz * y, pz * x - px, px * y - py * x
    kk0, kk1, kk2 = py * k2 - pz * k1, pz * k0 - px * k2, px * k1 - py * k0
    rx, ry, rz = x + a * k0 + b * kk0, y + a * k1 + b * kk1, 1.0 + a * k2 + b * kk2
    forward = rz > 0.1
    iz = 1.0 / (rz if forward else 1.0)
    u = ((fx * rx * iz + cx) + 0.5) * inv - 0.5
    v = ((fy * ry * iz + cy) + 0.5) * inv - 0.5
    if not with_gradient:
        return u, v, forward, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # -du/dφ = J(φ)ᵀ (g x r) for g = du/dr, and Jᵀ h = h - b φ x h + c (φ (φ·h) - θ² h)
    g0, g2 = fx * iz * inv, -fx * rx * iz * iz * inv  # du/dr (its y component is 0)
    h0, h1, h2 = -g2 * ry, g2 * rx - g0 * rz, g0 * ry
    ph = px * h0 + py * h1 + pz * h2
    c0, c1, c2 = py * h2 - pz * h1, pz * h0 - px * h2, px * h1 - py * h0
    u0 = h0 - b * c0 + c * (px * ph - theta2 * h0)
    u1 = h1 - b * c1 + c * (py * ph - theta2 * h1)
    u2 = h2 - b * c2 + c * (pz * ph - theta2 * h2)
    g1, g2 = fy * iz * inv, -fy * ry * iz * iz * inv  # dv/dr (its x component is 0)
    h0, h1, h2 = g1 * rz - g2 * ry, g2 * rx, -g1 * rx
    ph = px * h0 + py * h1 + pz * h2
    c0, c1, c2 = py * h2 - pz * h1, pz * h0 - px * h2, px * h1 - py * h0
    v0 = h0 - b * c0 + c * (px * ph - theta2 * h0)
    v1 = h1 - b * c1 + c * (py * ph - theta2 * h1)
    v2 = h2 - b * c2 + c * (pz * ph - theta2 * h2)
    return u, v, forward, u0, u1, u2, v0, v1, v2


@numba.njit(cache=True, nogil=True, fastmath=True)
def warp(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    params: np.ndarray,
    intrinsics: np.ndarray,
    scale: float,
    with_gradient: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Warp rays ``(bx, by, 1)`` fired ``dt`` s before t_ref to t_ref.

    ``params``: ω (3,) rad/s, a constant rotation; or (6,), ω_ref (rad/s) and α (rad/s²) of a
    rotation whose rate changes linearly, ``ω(t) = ω_ref + α (t - t_ref)``. An event ``dt`` s
    before t_ref is rotated by ``φ = -(ω_ref dt - α dt²/2)``, the integral of ω(t) over ``dt``
    (exact when α is parallel to ω, to second order in the angle otherwise).

    Args:
        intrinsics: ``(fx, fy, cx, cy)`` pixels of the full-resolution pinhole.
        scale: image downscale factor (pixel centres stay at integer coordinates).

    Returns:
        ``(u, v, valid, du, dv)``: pixel coordinates (N,), whether the ray still points forward
        (N,), and, with ``with_gradient``, d u/d params and d v/d params (N, 3 or 6) in px per
        unit (``dφ/dω = -dt``, ``dφ/dα = dt²/2``).
    """
    n, k = bx.shape[0], params.shape[0]
    m = n if with_gradient else 0
    u, v, valid = np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_)
    du, dv = np.empty((k, m)), np.empty((k, m))
    _warp_into(bx, by, dt, params, intrinsics, scale, u, v, valid, du, dv)
    return u, v, valid, du.T, dv.T


@numba.njit(cache=True, nogil=True, fastmath=True)
def _warp_into(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    params: np.ndarray,
    intrinsics: np.ndarray,
    scale: float,
    u: np.ndarray,
    v: np.ndarray,
    valid: np.ndarray,
    du: np.ndarray,
    dv: np.ndarray,
) -> None:
    """:func:`warp` into given arrays; the gradient where ``du`` and ``dv`` (k, N), one row per
    parameter, have columns."""
    k = params.shape[0]
    inv = 1.0 / scale
    with_gradient = du.shape[1] > 0
    if k == 3 and _small_angles(params, dt):
        _warp_small(bx, by, dt, params, intrinsics, inv, u, v, valid, du, dv, with_gradient)
        return
    for i in range(bx.shape[0]):
        d = dt[i]
        h = 0.5 * d * d if k == 6 else 0.0
        a0, a1, a2 = (params[3], params[4], params[5]) if k == 6 else (0.0, 0.0, 0.0)
        px, py, pz = -params[0] * d + a0 * h, -params[1] * d + a1 * h, -params[2] * d + a2 * h
        theta2 = px * px + py * py + pz * pz
        a, b, c = _rotation_coefficients(theta2)
        u[i], v[i], valid[i], u0, u1, u2, v0, v1, v2 = _project(
            a, b, c, theta2, px, py, pz, bx[i], by[i], intrinsics, inv, with_gradient
        )
        if with_gradient:
            du[0, i], du[1, i], du[2, i] = d * u0, d * u1, d * u2
            dv[0, i], dv[1, i], dv[2, i] = d * v0, d * v1, d * v2
            if k == 6:
                du[3, i], du[4, i], du[5, i] = -h * u0, -h * u1, -h * u2
                dv[3, i], dv[4, i], dv[5, i] = -h * v0, -h * v1, -h * v2


@numba.njit(cache=True, nogil=True, fastmath=True)
def _small_angles(params: np.ndarray, dt: np.ndarray) -> bool:
    """Whether constant ω ``params`` (3,) turns every event's ray by θ² < ``SMALL_ANGLE2``."""
    longest = 0.0
    for i in range(dt.shape[0]):
        longest = max(longest, abs(dt[i]))
    w2 = params[0] * params[0] + params[1] * params[1] + params[2] * params[2]
    return w2 * longest * longest < SMALL_ANGLE2


@numba.njit(cache=True, nogil=True, fastmath=True)
def _warp_small(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    params: np.ndarray,
    intrinsics: np.ndarray,
    inv: float,
    u: np.ndarray,
    v: np.ndarray,
    valid: np.ndarray,
    du: np.ndarray,
    dv: np.ndarray,
    with_gradient: bool,
) -> None:
    """:func:`_warp_into` of a constant ω under which every angle is small: the same values
    from the Taylor coefficients only, in a loop without branches, which vectorizes (the warp
    was the objective's largest cost)."""
    # Two loops, each calling with a constant: a body without branches.
    if not with_gradient:
        for i in range(bx.shape[0]):
            a, b, c, t2, px, py, pz = _small_turn(params, dt[i])
            u[i], v[i], valid[i], _, _, _, _, _, _ = _project(
                a, b, c, t2, px, py, pz, bx[i], by[i], intrinsics, inv, False
            )
        return
    for i in range(bx.shape[0]):
        d = dt[i]
        a, b, c, t2, px, py, pz = _small_turn(params, d)
        u[i], v[i], valid[i], u0, u1, u2, v0, v1, v2 = _project(
            a, b, c, t2, px, py, pz, bx[i], by[i], intrinsics, inv, True
        )
        du[0, i], du[1, i], du[2, i] = d * u0, d * u1, d * u2
        dv[0, i], dv[1, i], dv[2, i] = d * v0, d * v1, d * v2


@numba.njit(cache=True, nogil=True, fastmath=True, inline="always")
def _small_turn(omega: np.ndarray, d: float) -> tuple[float, ...]:
    """``a, b, c, θ², φx, φy, φz`` of :func:`_project` for φ = -ω ``d``, a small angle."""
    px, py, pz = -omega[0] * d, -omega[1] * d, -omega[2] * d
    theta2 = px * px + py * py + pz * pz
    a, b, c = _taylor_coefficients(theta2)
    return a, b, c, theta2, px, py, pz


@numba.njit(cache=True, nogil=True, fastmath=True)
def accumulate(
    u: np.ndarray, v: np.ndarray, weights: np.ndarray, valid: np.ndarray, width: int, height: int
) -> np.ndarray:
    """Bilinear voting of points (u, v) (pixels) with ``weights`` into a (height, width) image.

    Votes falling outside the image are dropped.
    """
    image = np.empty((height, width))
    _vote_into(u, v, weights, valid, image)
    return image


@numba.njit(cache=True, nogil=True, fastmath=True)
def _vote_into(
    u: np.ndarray, v: np.ndarray, weights: np.ndarray, valid: np.ndarray, image: np.ndarray
) -> None:
    """:func:`accumulate` into ``image`` (H, W), which it clears first."""
    height, width = image.shape
    image[:] = 0.0
    for i in range(u.shape[0]):
        if not valid[i]:
            continue
        fu0 = math.floor(u[i])
        fv0 = math.floor(v[i])
        x0, y0 = int(fu0), int(fv0)
        fu, fv = u[i] - fu0, v[i] - fv0
        w = weights[i]
        if 0 <= y0 < height:
            if 0 <= x0 < width:
                image[y0, x0] += w * (1.0 - fu) * (1.0 - fv)
            if 0 <= x0 + 1 < width:
                image[y0, x0 + 1] += w * fu * (1.0 - fv)
        if 0 <= y0 + 1 < height:
            if 0 <= x0 < width:
                image[y0 + 1, x0] += w * (1.0 - fu) * fv
            if 0 <= x0 + 1 < width:
                image[y0 + 1, x0 + 1] += w * fu * fv


def contrast(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    weights: np.ndarray,
    params: np.ndarray,
    intrinsics: np.ndarray,
    scale: float,
    width: int,
    height: int,
    taps: np.ndarray,
    with_gradient: bool,
) -> tuple[float, np.ndarray]:
    """Variance of the blurred IWE at ``1/scale`` resolution under :func:`warp`'s ``params``
    (ω, or ω_ref and α) and its gradient wrt them.

    ``width``, ``height`` are the IWE's size at that resolution; ``taps`` the Gaussian's.
    The arrays of the computation are this thread's scratch (:func:`_scratch`), reused from
    call to call.
    """
    n, k = bx.shape[0], params.shape[0]
    m = n if with_gradient else 0
    pixels = width * height
    floats, flags = _scratch(2 * n + 2 * m * k + 2 * pixels + width + taps.shape[0] - 1, n)
    return _contrast_into(
        bx, by, dt, weights, params, intrinsics, scale, width, height, taps, m, floats, flags
    )


_local = threading.local()


def _scratch(floats: int, flags: int) -> tuple[np.ndarray, np.ndarray]:
    """This thread's scratch arrays: at least ``floats`` float64 and ``flags`` booleans.

    Kept and reused because fresh arrays of the objective's size are mapped by the C
    allocator and faulted in page by page at every call. Per thread, since the live engine's
    searches and tests run on threads of their own.
    """
    have = getattr(_local, "arrays", None)
    if have is None or len(have[0]) < floats or len(have[1]) < flags:
        size = max(floats, len(have[0]) if have else 0)
        have = _local.arrays = (np.empty(size), np.empty(max(flags, 1), dtype=np.bool_))
    return have


@numba.njit(cache=True, nogil=True, fastmath=True)
def _contrast_into(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    weights: np.ndarray,
    params: np.ndarray,
    intrinsics: np.ndarray,
    scale: float,
    width: int,
    height: int,
    taps: np.ndarray,
    m: int,
    floats: np.ndarray,
    flags: np.ndarray,
) -> tuple[float, np.ndarray]:
    """:func:`contrast` on scratch arrays ``floats`` and ``flags``; ``m``: N with the gradient,
    else 0."""
    n, k, pixels = bx.shape[0], params.shape[0], width * height
    u, v = floats[:n], floats[n : 2 * n]
    du = floats[2 * n : 2 * n + m * k].reshape((k, m))
    dv = floats[2 * n + m * k : 2 * n + 2 * m * k].reshape((k, m))
    rest = 2 * n + 2 * m * k
    image = floats[rest : rest + pixels].reshape((height, width))
    blurred = floats[rest + pixels : rest + 2 * pixels].reshape((height, width))
    row = floats[rest + 2 * pixels : rest + 2 * pixels + width + taps.shape[0] - 1]
    valid = flags[:n]
    _warp_into(bx, by, dt, params, intrinsics, scale, u, v, valid, du, dv)
    _vote_into(u, v, weights, valid, image)
    _blur_into(image, taps, blurred, row)
    variance = _centre(blurred)
    gradient = np.zeros(k)
    if m == 0:
        return variance, gradient
    q = image  # the votes are no longer needed
    _blur_into(blurred, taps, q, row)
    for i in range(n):
        if not valid[i]:
            continue
        fu0 = math.floor(u[i])
        fv0 = math.floor(v[i])
        x0, y0 = int(fu0), int(fv0)
        fu, fv = u[i] - fu0, v[i] - fv0
        q00 = q[y0, x0] if 0 <= y0 < height and 0 <= x0 < width else 0.0
        q10 = q[y0, x0 + 1] if 0 <= y0 < height and 0 <= x0 + 1 < width else 0.0
        q01 = q[y0 + 1, x0] if 0 <= y0 + 1 < height and 0 <= x0 < width else 0.0
        q11 = q[y0 + 1, x0 + 1] if 0 <= y0 + 1 < height and 0 <= x0 + 1 < width else 0.0
        # d/du and d/dv of Σ_corners q * bilinear weight
        gu = (1.0 - fv) * (q10 - q00) + fv * (q11 - q01)
        gv = (1.0 - fu) * (q01 - q00) + fu * (q11 - q10)
        w = weights[i]
        for j in range(k):
            gradient[j] += w * (gu * du[j, i] + gv * dv[j, i])
    return variance, gradient * (2.0 / pixels)


@numba.njit(cache=True, nogil=True, fastmath=True)
def _centre(image: np.ndarray) -> float:
    """Subtract the mean of (H, W) ``image`` from it in place; returns its variance."""
    height, width = image.shape
    total = 0.0
    for y in range(height):
        for x in range(width):
            total += image[y, x]
    mean = total / (height * width)
    square = 0.0
    for y in range(height):
        for x in range(width):
            c = image[y, x] - mean
            image[y, x] = c
            square += c * c
    return square / (height * width)


@numba.njit(cache=True, nogil=True, fastmath=True)
def grid_contrast(
    bx: np.ndarray,
    by: np.ndarray,
    dt: np.ndarray,
    weights: np.ndarray,
    omegas: np.ndarray,
    intrinsics: np.ndarray,
    scale: float,
    width: int,
    height: int,
    taps: np.ndarray,
) -> np.ndarray:
    """Contrast (no gradient) for each of ``omegas`` (M, 3) rad/s under the warp to first order
    in the rotation angle, each event voting whole into its nearest pixel: the grid search's
    scores, which only rank its starting points (BFGS refines them with :func:`warp`).

    To first order, rotating ray ``(x, y, 1)`` by φ moves its image by
    ``fx (-xy φx + (1 + x²) φy - y φz)`` and ``fy (-(1 + y²) φx + xy φy + x φz)`` pixels, so
    each event costs six multiply-adds and one vote per ω; the second-order error is about
    ``f |φ|² / 2``: 3 px at 40 px of motion with f = 245 px, under a pixel at the grid's
    coarse level, whose blur is wider.
    """
    n = bx.shape[0]
    inv = 1.0 / scale
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    u0 = np.empty(n)
    v0 = np.empty(n)
    ju = np.empty((n, 3))
    jv = np.empty((n, 3))
    for i in range(n):
        x, y = bx[i], by[i]
        # +0.5 more than the pixel centre, so that floor() rounds to the nearest pixel
        u0[i] = ((fx * x + cx) + 0.5) * inv
        v0[i] = ((fy * y + cy) + 0.5) * inv
        su, sv = -fx * inv * dt[i], -fy * inv * dt[i]  # φ = -ω dt
        ju[i, 0], ju[i, 1], ju[i, 2] = -su * x * y, su * (1.0 + x * x), -su * y
        jv[i, 0], jv[i, 1], jv[i, 2] = -sv * (1.0 + y * y), sv * x * y, sv * x
    out = np.empty(omegas.shape[0])
    image, blurred = np.empty((height, width)), np.empty((height, width))
    row = np.empty(width + taps.shape[0] - 1)
    for k in range(omegas.shape[0]):
        w0, w1, w2 = omegas[k, 0], omegas[k, 1], omegas[k, 2]
        image[:] = 0.0
        for i in range(n):
            xi = math.floor(u0[i] + ju[i, 0] * w0 + ju[i, 1] * w1 + ju[i, 2] * w2)
            yi = math.floor(v0[i] + jv[i, 0] * w0 + jv[i, 1] * w1 + jv[i, 2] * w2)
            if 0 <= xi < width and 0 <= yi < height:
                image[yi, xi] += weights[i]
        _blur_into(image, taps, blurred, row)
        out[k] = _centre(blurred)
    return out
