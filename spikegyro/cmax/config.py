"""Settings of the contrast-maximization estimator (:class:`CMaxConfig`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from spikegyro.cmax.windows import WindowPolicy

Progress = Callable[[int, int], Any]
"""``progress(done, total)``, called as work advances."""


@dataclass(frozen=True)
class OneRotationTest:
    """Settings of the test whether one rotation explains a window's events
    (:mod:`spikegyro.cmax.confidence`).

    Attributes:
        min_agreement: the halves agree when each one's ω achieves at least this share of the
            other's own sharpening (see the module).
        min_gain: a window (or a half, by its own best rotation) whose contrast is under this
            times that of ω = 0 shows no structure that the rotation sharpens (a half: none to
            judge its agreement by).
        min_reversal: ω must sharpen the window, and every half of it with enough events, at
            least this much more than the reverse rotation -ω does (contrast at ω over that at
            -ω): where nothing moves with ω, ω and -ω blur alike (ratio 1).
        judge_px: where ω moves edges less than this over the window (binned px), a weak
            sharpening alone (a gain under ``min_gain`` or a ratio under ``min_reversal``) says
            that the motion is too little to tell from none (``ill_posed`` bit 2): so little
            motion blurs little under any rotation.
        max_area: the events' core (the ``core`` share of them nearest their median) spread over
            less than this share of the view (the area of its covariance ellipse over that of
            events spread evenly over the sensor) is one compact object: a camera's rotation
            lights up the textured view beyond one blob (:func:`~spikegyro.cmax.confidence.spread`).
        min_width: ... unless the core is a line, narrower than this share of its length: the
            events of one straight edge look the same whether it moves or the camera pans past
            it, and a rotating camera sees one long edge often (a bar, a door frame).
        core: the share of a window's events, nearest their median, that ``max_area`` measures
            (the rest: sensor noise scattered over the view).
        quiet_ms: within this long (ms of event time) after the view was quiet (too few events
            for a well-posed window: ``ill_posed`` bit 1, or none at all), events spread over
            less than ``max_area`` are an object entering a still camera's view even when they
            form a line (the live engine only).
        min_events: halves with fewer events are not judged.
        iterations: BFGS iterations refining each half's ω from the window's.
        max_events: events (random subsample) each half keeps at most (speed).
        scale: image downscale factor the halves are compared at (speed).
        every_ms: the live engine runs the test at most this often (ms of event time), on a
            thread of its own, its verdict applies from the next estimate until the next test's
            (the stream's first at once) (speed).
    """

    min_agreement: float = 0.9
    min_gain: float = 1.05
    min_reversal: float = 1.05
    judge_px: float = 5.0
    max_area: float = 0.2
    min_width: float = 0.3
    core: float = 0.9
    quiet_ms: float = 1000.0
    min_events: int = 500
    iterations: int = 1
    max_events: int = 1500
    scale: int = 2
    every_ms: float = 50.0


@dataclass(frozen=True)
class CMaxConfig:
    """Settings of the contrast-maximization estimator.

    Streams (:class:`~spikegyro.cmax.live.CMaxEstimator`):
        rate_hz: estimates per second of event time; 0: one per event batch.
        window: how long each causal window is (adaptive by default; see ``WindowPolicy``).
        track_events: events (evenly thinned) a tracking estimate uses at most (speed).
        track_iterations: BFGS iterations of a tracking estimate (warm-started, curvature
            included).
        track_xtol_px: a tracking estimate stops once a step moves edges less than this, px.
        search_every_s: the global search runs at the first estimate and then every this many
            seconds of event time (0: only at the first), the tracked estimate competing.
        search_lag_ms: a search after the first runs on a thread of lowest priority, and its ω
            is refined on, and competes at, the first estimate this many ms of event time after
            the search's own (the engine waits for it there: long enough that on one core the
            search fits in the time the estimates leave).
        search_in_line: the searches that cannot wait (the stream's first, and those after a
            collapse of the contrast gain, below) run the global search in line. Otherwise
            (default) they refine ω = 0 and the tracked ω coarse to fine in line and run the
            global search on that thread, taken up ``search_lag_ms`` later: its grid and
            starts would hold up every estimate behind it by about 0.1 s of CPU time.
        urgent_iterations: BFGS iterations per pyramid level of that in-line part (the
            estimates after it go on refining).
        min_motion_px: estimates moving edges by less than this over their window are flagged
            ill-posed (too little motion to tell from none).
        gain_drop: when an estimate's contrast gain above 1 falls below this share of its
            recent best, or it is ill-posed, the next search comes after a fifth of
            ``search_every_s``; below half this share, at the next estimate (in line: the
            motion may have changed abruptly) while their budget allows.
        collapse_gap_ms: that budget: at most one such search per this many ms of event time
            (0: no limit). On scenes of weak contrast the gain falls that far every few
            estimates, and each search costs tens of estimates' work.
        accelerating: each estimate is then refined once more under a rotation whose rate
            changes linearly (ω at the window's end and its rate of change α,
            :func:`~spikegyro.cmax.iwe.warp`), warm-started from the window's
            mean rate and the previous α, and reports ω at the window's end instead of the
            window's mean rate.
        bend_window: that fit uses the events of this many times the window's span (the bend
            α puts into the warp grows with the square of the span).
        bend_iterations: BFGS iterations of that fit.
        bend_cost: how much an α that bends the warp costs, as a share of the contrast per
            pixel² of displacement at the fit's far end, so that α stays near 0 where the
            events do not determine it.

    One window (:func:`estimate_window`, :func:`search`):
        max_events: windows with more events are randomly subsampled to this many (speed).
        min_events: windows with fewer events give no estimate (the previous one, or zero).
        hot_pixel_factor: drop pixels firing more than this times the 95th percentile of
            the pixel counts (see :mod:`spikegyro.cmax.windows`); 0 keeps all.
        levels: image downscale factors of the pyramid, coarse to fine (the last is 1).
        sigma_px: Gaussian smoothing of the IWE, pixels of each pyramid level.
        iterations: BFGS iterations per pyramid level of the search.
        coarse_xtol_px: the search's refinement at a coarse level stops once a step moves
            edges less than this (that level's pixels): it only has to start the next level
            within reach of its maximum.
        grid_points: grid points per axis of the global search (odd, so 0 is on the grid).
        grid_max_dps: the grid spans at most ``±grid_max_dps`` deg/s on each axis ...
        grid_max_px: ... and at most ``±grid_max_px`` pixels of displacement at the window's ends.
        grid_events: events (random subsample) scored by the grid.
        starts: how many of the best grid points are refined (besides zero and the warm start).
        search_events: events (random subsample) used to refine and compare the starts.
        seed: seed of the event subsampling.
        max_pixels: the objective's image at pyramid scale 1 has at most this many pixels:
            larger sensors are binned by a whole factor (``base_scale`` in
            :mod:`spikegyro.cmax.problem`; 1 at 240x180 and 346x260, 4 at 1280x720), and
            ``target_px`` and ``min_motion_px`` count binned pixels; 0: the sensor's pixels.
        ingest_rate: a stream keeps at most about this many events per second of event time
            (each 10 ms keeps every k-th event, k from the previous 10 ms's count), so that
            per-event work stops growing with the rate; 0: every event.
        one_rotation: the test of ``ill_posed`` bit 4 (:mod:`spikegyro.cmax.confidence`; None:
            not run).
    """

    rate_hz: float = 100.0
    window: WindowPolicy = field(default_factory=WindowPolicy)
    track_events: int = 10_000
    track_iterations: int = 2
    track_xtol_px: float = 0.05
    search_every_s: float = 3.0
    search_lag_ms: float = 1000.0
    search_in_line: bool = False
    urgent_iterations: int = 5
    min_motion_px: float = 1.0
    gain_drop: float = 0.6
    collapse_gap_ms: float = 250.0
    accelerating: bool = False
    bend_window: float = 2.0
    bend_iterations: int = 4
    bend_cost: float = 0.0
    max_events: int = 30_000
    min_events: int = 100
    hot_pixel_factor: float = 5.0
    levels: tuple[int, ...] = (4, 2, 1)
    sigma_px: float = 1.0
    iterations: int = 20
    coarse_xtol_px: float = 0.1
    grid_points: int = 11
    grid_max_dps: float = 1000.0
    grid_max_px: float = 40.0
    grid_events: int = 2000
    starts: int = 3
    search_events: int = 4000
    seed: int = 0
    max_pixels: int = 100_000
    ingest_rate: float = 1e6
    one_rotation: OneRotationTest | None = field(default_factory=OneRotationTest)
