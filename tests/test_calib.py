"""Calibration: distortion model, its inverse, pinhole reprojection and the event mapping."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.errors import InputError
from spikegyro.events.calib import Calibration, PinholeCamera, load_calibration
from spikegyro.events.core import EventArray

# The Event Camera Dataset's DAVIS240C calibration (shapes/boxes/poster sequences).
ECD_LINE = "199.092366542 198.82882047 132.192071378 110.712660011 -0.368436311798 0.150947243557 -0.000296130534385 -0.000759431726241 0.0"  # noqa: E501
ECD = Calibration(*map(float, ECD_LINE.split()))


def test_distort_matches_hand_computed_point():
    calib = Calibration(100.0, 100.0, 0.0, 0.0, k1=0.1, k2=0.01, p1=0.001, p2=0.002, k3=0.001)
    # x = 0.3, y = -0.4: r2 = 0.25, radial = 1 + 0.025 + 0.000625 + 0.000015625 = 1.025640625
    # xd = 0.3 * radial + 2 * 0.001 * (-0.12) + 0.002 * (0.25 + 0.18)
    #    = 0.3076921875 - 0.00024 + 0.00086
    # yd = -0.4 * radial + 0.001 * (0.25 + 0.32) + 2 * 0.002 * (-0.12)
    #    = -0.41025625 + 0.00057 - 0.00048
    xd, yd = calib.distort(np.array(0.3), np.array(-0.4))
    assert float(xd) == pytest.approx(0.3083121875, abs=1e-12)
    assert float(yd) == pytest.approx(-0.41016625, abs=1e-12)


def test_undistort_inverts_the_forward_model_over_the_ecd_sensor():
    rng = np.random.default_rng(0)
    # ideal points spanning the DAVIS240C field of view (|x| < 0.62, |y| < 0.55)
    x = rng.uniform(-0.62, 0.62, 2000)
    y = rng.uniform(-0.55, 0.55, 2000)
    xd, yd = ECD.distort(x, y)
    xu, yu = ECD.undistort(xd, yd)
    np.testing.assert_allclose(xu, x, atol=1e-10)
    np.testing.assert_allclose(yu, y, atol=1e-10)


def test_pixel_rays_of_distorted_projection_are_the_original_rays():
    # Project known rays through the distorted camera, then ask for the rays of those pixels.
    x, y = np.array([0.0, 0.2, -0.5, 0.4]), np.array([0.0, -0.3, 0.35, 0.45])
    xd, yd = ECD.distort(x, y)
    u, v = ECD.fx * xd + ECD.cx, ECD.fy * yd + ECD.cy
    xr, yr = ECD.pixel_rays(u, v)
    np.testing.assert_allclose(xr, x, atol=1e-10)
    np.testing.assert_allclose(yr, y, atol=1e-10)


def test_pinhole_with_other_intrinsics_maps_pixel_rays():
    source = Calibration(fx=150.0, fy=150.0, cx=160.0, cy=120.0)  # wider view than the target
    target = PinholeCamera.default()
    lut = source.lookup_table(320, 240, target)
    # source pixel (190, 60) is the ray (0.2, -0.4) -> target (120 + 40, 90 - 80)
    assert lut[60, 190] == 10 * 240 + 160
    # the principal point maps to the principal point
    assert lut[120, 160] == 90 * 240 + 120
    # pixel (0, 120) is the ray x/z = -16/15, outside the target's half-width of 0.6
    assert lut[120, 0] == -1
    # target columns 0..239 cover u in [-0.5, 239.5): source columns 160 + 0.75 * (u - 120),
    # i.e. 69.625 .. 249.625 -> the 180 source columns 70..249 on the centre row
    assert np.flatnonzero(lut[120] >= 0).tolist() == list(range(70, 250))


def test_identity_calibration_is_identity_on_the_default_camera():
    calib = Calibration(200.0, 200.0, 120.0, 90.0)
    lut = calib.lookup_table(240, 180, PinholeCamera.default())
    np.testing.assert_array_equal(lut, np.arange(240 * 180).reshape(180, 240))


def test_scaled_camera_keeps_the_field_of_view():
    half = PinholeCamera.default(0.5)
    assert (half.width, half.height, half.fx) == (120, 90, 100.0)
    # the edges of the full image land on the edges of the half image
    calib = Calibration(200.0, 200.0, 120.0, 90.0)
    lut = calib.lookup_table(240, 180, half)
    assert lut[90, 0] // 120 in (44, 45) and lut[90, 0] % 120 == 0
    assert lut[90, 239] % 120 == 119


def test_map_events_sends_distorted_points_to_the_model_pixels():
    target = PinholeCamera.default()
    # rays that land exactly on target pixel centres
    tu, tv = np.array([120, 30, 200, 60]), np.array([90, 20, 150, 160])
    x, y = (tu - target.cx) / target.fx, (tv - target.cy) / target.fy
    xd, yd = ECD.distort(x, y)
    u, v = np.rint(ECD.fx * xd + ECD.cx), np.rint(ECD.fy * yd + ECD.cy)
    events = EventArray.from_arrays(u, v, [0, 1, 2, 3], [1, 0, 1, 0], 240, 180)
    mapped = ECD.map_events(events, target)
    # rounding the sensor pixel moves the ray by < 0.5 px * (200 / 199) / local magnification
    assert len(mapped) == 4
    assert np.all(np.abs(mapped.x - tu) <= 1) and np.all(np.abs(mapped.y - tv) <= 1)
    np.testing.assert_array_equal(mapped.t, events.t)
    np.testing.assert_array_equal(mapped.p, events.p)
    assert (mapped.width, mapped.height) == (240, 180)


def test_map_events_drops_events_outside_the_target():
    calib = Calibration(100.0, 100.0, 120.0, 90.0)  # wider field of view than the target
    events = EventArray.from_arrays([0, 120, 239], [0, 90, 179], [0, 1, 2], [1, 1, 1], 240, 180)
    mapped = calib.map_events(events, PinholeCamera.default())
    np.testing.assert_array_equal(mapped.x, [120])
    np.testing.assert_array_equal(mapped.y, [90])
    np.testing.assert_array_equal(mapped.t, [1])


def test_load_ecd_calib_txt(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(ECD_LINE + "\n")
    assert load_calibration(path) == ECD
    path.write_text("200 201 120 90\n")
    assert load_calibration(path) == Calibration(200.0, 201.0, 120.0, 90.0)


@pytest.mark.parametrize("text", ["1 2 3", "a b c d", "-1 200 120 90"])
def test_load_calibration_rejects_bad_files(tmp_path, text):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=r"calib\.txt"):
        load_calibration(path)
