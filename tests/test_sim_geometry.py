"""Simulator geometry against closed forms: edge crossings, flow directions, the seam, SO(3)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from spikegyro.sim import (
    Camera,
    EventSimConfig,
    Panorama,
    Trajectory,
    random_trajectory,
    render,
    simulate,
    so3_exp,
)
from spikegyro.sim.trajectory import hat

EXACT = EventSimConfig(mismatch_std=0.0, noise_std=0.0)
DARK, BRIGHT = 0.2, 0.8


def edge_panorama(width: int = 1024, edge_col: int = 540) -> Panorama:
    """Dark for columns < edge_col, bright from edge_col on (a meridian edge)."""
    img = np.full((width // 2, width), DARK, np.float32)
    img[:, edge_col:] = BRIGHT
    return Panorama(img, "edge")


def test_vertical_edge_pan_emits_on_events_exactly_where_and_when_the_edge_crosses():
    width, edge_col, omega_y, duration = 1024, 540, 1.0, 0.2
    cam = Camera()
    pano = edge_panorama(width, edge_col)
    rec = simulate(pano, Trajectory.constant([0, omega_y, 0], duration), cam, EXACT)
    ev = rec.events
    assert len(ev) > 0
    # Dark-to-bright as the camera turns right (lon of each pixel grows): only ON events.
    assert (ev.p == 1).all()

    # Log-domain bilinear sampling makes L linear in longitude between the two texel centres
    # beside the edge; the k-th threshold is crossed at lon_k, and pixel x looks at
    # lon = atan((x - cx) / f) + omega_y * t, whatever its row.
    texel = 2 * np.pi / width
    lon_edge = edge_col * texel - np.pi
    contrast = np.log((1e-3 + BRIGHT) / (1e-3 + DARK))
    ks = np.arange(1, int(contrast / 0.45) + 1)
    lon_k = lon_edge - texel / 2 + texel * ks * 0.45 / contrast
    x = np.arange(cam.width)
    lon0 = np.arctan((x - cam.cx) / cam.fx)
    t_pred = (lon_k[None, :] - lon0[:, None]) / omega_y  # (W, k) seconds
    # Pixels that start fully on the dark side fire once per threshold crossed within the run.
    start_dark = lon0 < lon_edge - texel / 2
    expect_count = ((t_pred > 0) & (t_pred <= duration)).sum(1) * start_dark
    counts = np.zeros((cam.height, cam.width), int)
    np.add.at(counts, (ev.y, ev.x), 1)
    changed = ~start_dark | (lon0 > lon_edge + texel / 2 - omega_y * duration)
    np.testing.assert_array_equal(counts[:, ~changed], 0)  # the edge never reaches them
    assert (counts[:, start_dark] == expect_count[start_dark]).all()
    # Timestamps: within a fraction of the frame interval (about 1.8 ms here). ESIM interpolates
    # linearly between frames, which is exact on the ramp and off by up to about half an
    # interval only in the frame interval that straddles a corner of the ramp.
    t_s = ev.t / 1e6
    sel = start_dark[ev.x]
    err = np.abs(t_pred[ev.x[sel]] - t_s[sel, None]).min(1)
    frame_interval = duration / (rec.attrs["frames"] - 1)
    assert err.max() < 0.6 * frame_interval
    assert np.median(err) < 0.02 * frame_interval


def _event_centroid_motion(rec) -> tuple[float, float]:
    """Slopes (px/s) of event x and y against time (least squares)."""
    t = rec.events.t / 1e6
    vx = np.polyfit(t, rec.events.x.astype(float), 1)[0]
    vy = np.polyfit(t, rec.events.y.astype(float), 1)[0]
    return vx, vy


def test_pure_pan_moves_the_edge_left_at_f_omega():
    cam = Camera()
    rec = simulate(edge_panorama(), Trajectory.constant([0, 1.0, 0], 0.1), cam, EXACT)
    vx, vy = _event_centroid_motion(rec)
    # Edge at x ≈ cx + 34 px: speed f(1 + u²)ω ≈ 206 px/s, towards −x; no vertical drift.
    assert -240 < vx < -180
    assert abs(vy) < 5


def test_pure_tilt_moves_a_horizon_edge_down():
    cam = Camera()
    img = np.full((512, 1024), DARK, np.float32)
    img[:236] = BRIGHT  # bright sky above latitude +3.9 degrees
    rec = simulate(Panorama(img, "horizon"), Trajectory.constant([1.0, 0, 0], 0.1), cam, EXACT)
    vx, vy = _event_centroid_motion(rec)
    # Tilting up (ω_x > 0) moves the image down (+y) at about f ω: bright sky descends, ON events.
    assert 180 < vy < 240
    assert abs(vx) < 5
    assert rec.events.p.mean() > 0.99


def test_pure_roll_turns_the_image_clockwise_on_screen():
    cam = Camera()
    img = np.full((512, 1024), DARK, np.float32)
    img[:256] = BRIGHT  # horizon through the principal point
    rec = simulate(Panorama(img, "horizon"), Trajectory.constant([0, 0, 1.0], 0.05), cam, EXACT)
    ev = rec.events
    # Flow for roll: dv/dt = −u ω_z f: the right half rises (bright sky leaves: OFF), the left
    # half sinks (bright sky arrives: ON).
    right, left = ev.x > cam.cx + 5, ev.x < cam.cx - 5
    assert ev.p[right].mean() < 0.01
    assert ev.p[left].mean() > 0.99


def test_seam_is_continuous_and_static_camera_is_silent():
    rng = np.random.default_rng(3)
    img = rng.uniform(0.1, 1.0, (256, 512)).astype(np.float32)
    pano = Panorama(img, "noise")
    rolled = Panorama(np.roll(img, 256, axis=1), "rolled")
    cam = Camera(64, 48, 50, 50, 32, 24)
    for ang in (0.3, 1.0, 2.0):
        r = so3_exp(np.array([0.1, ang, 0.05]))
        # Looking across the seam of one equals looking across the middle of the other.
        across_seam = render(pano, so3_exp(np.array([0, np.pi, 0])) @ r, cam)
        np.testing.assert_allclose(across_seam, render(rolled, r, cam), atol=1e-4)
    at_seam = Trajectory.constant([0, 0, 0], 0.05, r0=so3_exp(np.array([0, np.pi, 0])))
    assert len(simulate(pano, at_seam, cam, EXACT).events) == 0


def test_orientation_matches_an_independent_ode_integration():
    traj = random_trajectory(np.random.default_rng(7), 0.5)

    def rhs(t, y):
        r = y.reshape(3, 3)
        return (r @ hat(traj.omega_at(t))).ravel()

    times = np.array([0.0, 0.1234, 0.3, 0.5])
    sol = solve_ivp(
        rhs, (0, 0.5), traj.r0.ravel(), t_eval=times, rtol=1e-10, atol=1e-12, max_step=1e-3
    )
    ref = sol.y.T.reshape(-1, 3, 3)
    np.testing.assert_allclose(traj.rotation_at(times), ref, atol=1e-7)


def test_constant_omega_orientation_is_the_exponential():
    w = np.array([0.3, -1.2, 2.0])
    traj = Trajectory.constant(w, 0.5)
    for t in (0.0, 0.01234, 0.5):
        np.testing.assert_allclose(traj.rotation_at(t), so3_exp(w * t), atol=1e-10)


@pytest.mark.parametrize("axis", [0, 1])
def test_mirrored_and_reversed_trajectories_trace_mirrored_and_reversed_paths(axis):
    traj = random_trajectory(np.random.default_rng(1), 0.2)
    m = np.diag([-1.0 if i == axis else 1.0 for i in range(3)])
    t = np.linspace(0, 0.2, 7)
    np.testing.assert_allclose(
        traj.mirrored(axis).rotation_at(t), m @ traj.rotation_at(t) @ m, atol=1e-9
    )
    np.testing.assert_allclose(traj.reversed().rotation_at(t), traj.rotation_at(0.2 - t), atol=1e-9)


@pytest.mark.parametrize("axis", [0, 1])
def test_mirrored_world_gives_the_flipped_event_stream(axis):
    # The training engineer's flip augmentation relies on this: a horizontally (vertically)
    # mirrored scene under the mirrored motion, seen by a centred camera, emits the flipped events.
    from spikegyro.sim import mirror_panorama
    from spikegyro.sim.procedural import procedural_panorama

    cam = Camera(48, 36, 40.0, 40.0, 23.5, 17.5)
    pano = procedural_panorama(np.random.default_rng(0), 512)
    traj = random_trajectory(np.random.default_rng(1), 0.1)
    ev = simulate(pano, traj, cam, EXACT).events
    fl = simulate(mirror_panorama(pano, axis), traj.mirrored(axis), cam, EXACT).events
    x, y = ev.x.astype(int), ev.y.astype(int)
    fx, fy = fl.x.astype(int), fl.y.astype(int)
    if axis == 0:
        fx = cam.width - 1 - fx
    else:
        fy = cam.height - 1 - fy
    a = np.lexsort((ev.t, ev.p, y, x))
    b = np.lexsort((fl.t, fl.p, fy, fx))
    assert len(ev) == len(fl) > 1000
    np.testing.assert_array_equal(np.stack([x, y, ev.p])[:, a], np.stack([fx, fy, fl.p])[:, b])
    # Only float32 rounding differs: timestamps agree to the µs but for a few shallow crossings.
    dt = np.abs(ev.t[a] - fl.t[b])
    assert (dt <= 1).mean() > 0.99 and dt.max() <= 50
