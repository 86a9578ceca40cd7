"""ill_posed bit 4 on composed recordings with known truth: objects moving before a still camera
are flagged (or read ω about 0), rotations are not; the measures behind the verdict (the
events' spread, the reverse rotation's blur) against geometry and the null of a still scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scene_helpers import Patch, compose, moving, noise_events, patch_events, scenes
from test_cmax import HEIGHT, WIDTH
from test_cmax_confidence import CAMERA

from spikegyro.cmax.confidence import rotation_agreement, spread
from spikegyro.cmax.config import CMaxConfig, OneRotationTest
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.problem import make_problem
from spikegyro.cmax.windows import WindowPolicy
from spikegyro.events.core import EventArray
from spikegyro.stream.estimator import ILL_NOT_ONE_ROTATION

SCENES = scenes(0.6, seed=3)


def _problem(events: EventArray):
    return make_problem(events, CAMERA, CMaxConfig(), np.random.default_rng(0))


def test_spread_measures_the_share_of_the_view_and_the_width_of_known_shapes():
    rng = np.random.default_rng(1)
    area, width = spread(_problem(noise_events(2.0, 0.1, rng)))  # even over the sensor
    # The core leaves out the view's far corners: a little under 1.
    assert 0.8 < area < 0.95 and width == pytest.approx(HEIGHT / WIDTH, abs=0.05)
    # A 60 x 45 px rectangle is 1/16 of the view, a 4 x 150 px bar a line (the noise within
    # its core widens it a little); 5 % noise around them is mostly left out of the core.
    for (w, h), share, narrow in (((60, 45), 1 / 16, False), ((4, 150), None, True)):
        still = Patch(moving(120, 90), w, h, points=2000)
        events = compose(patch_events(still, 0.05, rng), noise_events(0.25, 0.05, rng))
        area, width = spread(_problem(events))
        if share is not None:
            assert area == pytest.approx(share, rel=0.35)
        line = width < OneRotationTest().min_width
        assert line if narrow else (width == pytest.approx(h / w, rel=0.15))


def test_the_reverse_rotation_blurs_as_much_where_nothing_moves_and_more_under_a_rotation():
    rng = np.random.default_rng(2)
    still = patch_events(Patch(moving(120, 90), 200, 150, points=3000, rate=300), 0.05, rng)
    omega = np.radians([20.0, 40.0, 0.0])  # not the scene's motion (none)
    found = rotation_agreement(_problem(still), omega)
    assert found.reversal == pytest.approx(1.0, abs=0.03)
    assert found.half_reversal == pytest.approx(1.0, abs=0.05) and not found.explains
    pan = SCENES["pan"][0].slice_time(200_000, 230_000)
    found = rotation_agreement(_problem(pan), np.radians([0.0, 60.0, 0.0]))
    assert found.reversal > 1.2 and found.half_reversal > 1.1 and found.explains


def _live(events: EventArray, config: CMaxConfig | None = None):
    est = CMaxEstimator(CAMERA, config).run(events)
    assert len(est) >= 10
    near_zero = np.degrees(np.linalg.norm(est.omega, axis=1)) <= 3.0
    return ((est.ill_posed > 0) | near_zero).mean(), ((est.ill_posed & ILL_NOT_ONE_ROTATION) > 0)


@pytest.mark.parametrize("name", [n for n, (_, still) in SCENES.items() if still])
def test_live_estimates_of_a_still_camera_watching_objects_are_flagged(name):
    flagged, _ = _live(SCENES[name][0])
    assert flagged >= 0.9


@pytest.mark.parametrize("name", [n for n, (_, still) in SCENES.items() if not still])
def test_live_estimates_of_rotations_rarely_carry_bit_4(name):
    _, bit4 = _live(SCENES[name][0])
    assert bit4.mean() <= 0.1


def test_a_bar_sweeping_a_quiet_view_is_flagged_because_the_view_was_quiet():
    events = SCENES["bar after silence"][0]
    # Without the memory of the quiet view, the sweep in windows of 3,000 events is what a pan
    # past a bar shows; with it, they and the default windows flag it.
    short = CMaxConfig(window=WindowPolicy(min_events=3000))
    forget = replace(short, one_rotation=OneRotationTest(quiet_ms=0.0))
    _, bit4 = _live(events, forget)
    assert bit4.mean() <= 0.1
    for config in (short, CMaxConfig()):
        _, bit4 = _live(events, config)
        assert bit4.mean() >= 0.9
