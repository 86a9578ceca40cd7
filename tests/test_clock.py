"""The event clock (spikegyro.events.clock) against independent references.

- step boundaries against a brute-force walk over the events one at a time;
- the mean of a trace over a step against closed-form integrals;
- a recording replayed k times faster gives, on the event clock, the same steps and k times ω
  (the streaming network run end to end), and rows that do not depend on how it was chunked;
- the training window of a span of steps (virtual times, labels) against the streaming run.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from stream_helpers import TinySNN, random_events

from spikegyro.errors import InputError
from spikegyro.events.clock import (
    STEP_US,
    Clock,
    EventClock,
    close_steps,
    mean_rates,
    step_rates,
    virtual_times,
)
from spikegyro.events.core import EventArray, GyroTrace
from spikegyro.stream.clocked import ClockedPredictor, RowHolder, clocked_per_ms
from spikegyro.stream.estimator import Estimates
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.predict import SNNEstimator, StreamPredictor
from spikegyro.stream.stateful import StreamingSNN
from spikegyro.train.augment import reverse_time
from spikegyro.train.data import clocked_window, encode_window

H, W = 48, 64
SPEC = {"representation": "spikes", "sensor": [W, H], "scale": 1.0, "output": "per_step"}


def brute_steps(t: np.ndarray, begin: int, clock: Clock, known: int) -> list[tuple[int, int]]:
    """(end, events) of each closed step, walking the events one at a time."""
    steps, i, n = [], 0, len(t)
    while True:
        count, j = 0, i
        end = None
        while j < n:  # take events until the N-th (and every event sharing its time)
            count += 1
            if count == clock.events_per_step:
                end = int(t[j])
                break
            j += 1
        end = begin + clock.max_step_us if end is None else end
        end = min(max(end, begin + clock.min_step_us), begin + clock.max_step_us)
        if not (n and t[-1] > end) and known < end:
            return steps
        k = i
        while k < n and t[k] <= end:
            k += 1
        steps.append((end, k - i))
        begin, i = end, k


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.integers(0, 5000), min_size=0, max_size=300),
    st.integers(1, 40),
    st.integers(1, 300),
    st.integers(0, 2000),
)
def test_steps_match_a_walk_over_the_events(times, count, min_us, extra_us):
    t = np.sort(np.array(times, np.int64))
    clock = Clock(count, min_us, min_us + extra_us)
    known = int(t[-1]) if len(t) else 0
    ends, cuts = close_steps(t, 0, clock, known_us=known)
    sizes = np.diff(np.concatenate([[0], cuts]))
    assert list(zip(ends.tolist(), sizes.tolist(), strict=True)) == brute_steps(t, 0, clock, known)
    # streaming in pieces closes the same steps
    stream, got = EventClock(clock, 0), []
    for piece in np.array_split(t, 7):
        got += list(zip(*stream.push(piece), strict=True))
    got += list(zip(*stream.finish(known), strict=True))
    assert [(int(e), int(c)) for e, c in got] == brute_steps(t, 0, clock, known)


def test_a_step_holds_n_events_within_its_bounds():
    t = np.arange(0, 100_000, 10)  # 100 events per ms
    ends, cuts = close_steps(t, 0, Clock(500, 1000, 20_000))
    assert np.all(np.diff(ends) == 5000) and np.all(np.diff(cuts) == 500)
    ends, _ = close_steps(t, 0, Clock(50, 1000, 20_000))  # the minimum binds: 1 ms steps
    assert np.all(np.diff(ends) == 1000)
    ends, cuts = close_steps(t[:5], 0, Clock(500, 1000, 20_000), known_us=100_000)
    assert ends.tolist()[:2] == [20_000, 40_000] and cuts[0] == 5  # the maximum binds


def test_virtual_times_keep_order_and_steps():
    t = np.sort(np.random.default_rng(0).integers(0, 50_000, 2000))
    ends, cuts = close_steps(t, 0, Clock(100, 1, 10**6))
    v = virtual_times(t, ends, cuts, 0)
    assert np.all(np.diff(v) >= 0)
    step = np.repeat(np.arange(len(ends)), np.diff(np.concatenate([[0], cuts])))
    assert np.array_equal(v // STEP_US, step)


def test_mean_rate_over_a_step_is_the_closed_form_integral():
    t = np.arange(0, 101) * 10_000  # 1 s of samples every 10 ms
    w = np.stack([np.sin(t / 1e6 * 3), t / 1e6, np.full(len(t), 2.0)], 1)
    a, b = np.array([12_345, 0, 500_000]), np.array([87_654, 1_000_000, 500_001])
    got = mean_rates(t, w, a, b)
    # linear pieces integrate exactly: the second and third axes are linear and constant
    assert np.allclose(got[:, 1], (a + b) / 2e6) and np.allclose(got[:, 2], 2.0)
    exact = (np.cos(a / 1e6 * 3) - np.cos(b / 1e6 * 3)) / 3 / ((b - a) / 1e6)
    assert np.allclose(got[:, 0], exact, atol=2e-4)  # the trace itself is linear between samples


@pytest.fixture(scope="module")
def tiny():
    torch.manual_seed(0)
    return spec_from_model(TinySNN(gain=4.0).eval(), (2, H, W))


def _run(spec, events: EventArray, clock: Clock, chunk: int) -> tuple[np.ndarray, ...]:
    predictor = ClockedPredictor(StreamPredictor(StreamingSNN(spec), W, 0), clock, 0)
    parts = [predictor.push(events[i : i + chunk]) for i in range(0, len(events), chunk)]
    parts.append(predictor.finish(int(events.t[-1]) + 1))
    return tuple(np.concatenate([p[k] for p in parts]) for k in (0, 1))


def test_a_recording_k_times_faster_gives_the_same_steps_and_k_times_omega(tiny):
    k = 4
    slow = random_events(W, H, 400, 0.05, seed=3)
    slow = EventArray(slow.x, slow.y, slow.t * k, slow.p, W, H)  # times divisible by k
    fast = EventArray(slow.x, slow.y, slow.t // k, slow.p, W, H)
    clock = Clock(60, 1, 10**9)  # no bound binds
    ends_slow, w_slow = _run(tiny, slow, clock, 1000)
    ends_fast, w_fast = _run(tiny, fast, clock, 777)
    assert len(ends_slow) == len(ends_fast) > 100
    assert np.array_equal(ends_slow, ends_fast * k)
    assert np.abs(w_slow).max() > 0  # the network answers
    assert np.allclose(w_fast, k * w_slow, rtol=1e-12, atol=1e-12)


def test_rows_do_not_depend_on_the_chunks(tiny):
    events = random_events(W, H, 300, 0.03, seed=4)
    spec = {**SPEC, "clock": Clock(80, 1000, 8000).as_dict()}
    tables = []
    for chunk in (500, 4321, len(events)):
        est = SNNEstimator(StreamingSNN(tiny), spec)
        est.reset(0)
        blocks = [est.update(events[i : i + chunk]) for i in range(0, len(events), chunk)]
        blocks.append(est.finish(300_000))
        tables.append(Estimates.concatenate(blocks))
    for other in tables[1:]:
        assert np.array_equal(tables[0].t_us, other.t_us)
        assert np.array_equal(tables[0].omega, other.omega)
    rows = tables[0]
    assert np.all(np.diff(rows.t_us) == 1000) and rows.t_us[-1] <= 300_000
    assert np.all(rows.delay_us >= 0) and np.all(rows.window_us >= 1000)


def test_a_row_holds_the_latest_step_that_ended_by_its_time():
    holder = RowHolder(0)
    ends = np.array([1500, 2500, 2600, 7000])
    omega = np.arange(12.0).reshape(4, 3)
    est = holder.rows(ends, omega, np.diff(np.concatenate([[0], ends])), np.ones(4), 7999)
    assert est.t_us.tolist() == [2000, 3000, 4000, 5000, 6000, 7000]
    assert est.omega[:, 0].tolist() == [0.0, 6.0, 6.0, 6.0, 6.0, 9.0]
    assert est.delay_us.tolist() == [500, 400, 1400, 2400, 3400, 0]
    assert holder.rows(np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(0), 9000).omega[
        :, 0
    ].tolist() == [9.0, 9.0]


def test_the_training_window_is_what_the_stream_runs(tiny):
    """The window of a span of steps, fed to the network as a 1 ms model, gives the stream's
    outputs; its labels times the step rate are the trace's mean over each step."""
    events = random_events(W, H, 200, 0.04, seed=5)
    t = np.arange(0, 201) * 1000
    omega = np.stack([np.sin(t / 5e4), np.cos(t / 7e4), t / 2e5], 1)
    gyro = GyroTrace.from_arrays(t, omega)
    clock = Clock(70, 500, 5000)
    window = clocked_window(events.slice_time, gyro, 0, 200_000, 50, clock)
    assert window is not None and window.num_steps == 50
    ends = np.cumsum(window.step_us)
    rates = step_rates(ends, 0)
    assert np.allclose(window.omega * rates[:, None], mean_rates(t, omega, ends - window.step_us,
                                                                  ends))  # fmt: skip
    ends_stream, w_stream = _run(tiny, events.slice_time(0, int(ends[-1]) + 1), clock, 900)
    assert np.array_equal(ends_stream[:50], ends)
    spikes = encode_window(window, {**SPEC, "window_ms": 50, "clock": clock.as_dict()})
    assert spikes.shape == (2, H, W, 50) and spikes.sum() > 0
    one_ms = StreamPredictor(StreamingSNN(tiny), W, 0)  # the window as a 1 ms model reads it
    outputs = np.concatenate([one_ms.push(window.events)[1], one_ms.finish(50 * STEP_US)[1]])
    assert np.allclose(outputs * rates[:, None], w_stream[:50], rtol=1e-12, atol=1e-12)


def test_time_reversal_reverses_the_steps():
    events = random_events(W, H, 100, 0.05, seed=6)
    t = np.arange(0, 101) * 1000
    gyro = GyroTrace.from_arrays(t, np.stack([t / 1e5, -t / 1e5, np.ones(len(t))], 1))
    window = clocked_window(events.slice_time, gyro, 0, 100_000, 20, Clock(150, 1, 10**6))
    back = reverse_time(window)
    assert np.array_equal(back.step_us, window.step_us[::-1])
    assert np.allclose(back.omega, -window.omega[::-1])
    assert np.array_equal(reverse_time(back).events.t, window.events.t)


def test_per_ms_reading_is_zero_before_the_first_step(tiny):
    events = random_events(W, H, 50, 0.02, seed=7)
    predictor = ClockedPredictor(StreamPredictor(StreamingSNN(tiny), W, 0), Clock(200, 1, 10**6), 0)
    series = clocked_per_ms(predictor, events, 0, 50)
    first = int(np.ceil(close_steps(events.t, 0, Clock(200, 1, 10**6))[0][0] / 1000))
    assert series.shape == (50, 3) and not series[: first - 1].any()


@pytest.mark.parametrize("text", ["events:0", "events", "events:10:5-1", "seconds", "events:5:x"])
def test_a_bad_clock_is_one_clear_error(text):
    with pytest.raises(InputError, match="clock"):
        Clock.parse(text)


def test_clock_text_round_trips():
    assert Clock.parse("paper").is_paper
    assert Clock.parse("events:500:0.5-30") == Clock(500, 500, 30_000)
    assert Clock.from_dict(Clock(7, 2, 3).as_dict()) == Clock(7, 2, 3)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_the_output_gain_undoes_the_focal_length_of_the_flow(axis):
    """A sensor of other focal lengths moves edges by f·ω for tilt and pan and by ω·r for roll:
    the flow the model's camera would see for ω is the sensor's flow for ω / gain."""
    from spikegyro.events.calib import Calibration
    from spikegyro.sim.camera import Camera
    from spikegyro.stream.predict import model_camera, output_gain

    spec = {**SPEC, "sensor": [240, 180], "pixels": "sensor"}
    model = model_camera(spec)
    # tilt and pan with non-square pixels; roll's ω·r holds for square ones
    calib = Calibration(245.0, 300.0 if axis < 2 else 245.0, 121.0, 88.0)
    sensor = Camera(240, 180, calib.fx, calib.fy, calib.cx, calib.cy)
    ideal = Camera(240, 180, model.fx, model.fy, model.cx, model.cy)
    omega = np.zeros(3)
    omega[axis] = 0.5
    gain = output_gain(spec, calib)
    # at pixels the same distance from each principal point (the window centres it)
    dx, dy = np.array([0.0, 40.0, -30.0]), np.array([0.0, -20.0, 35.0])
    seen = sensor.flow(omega, calib.cx + dx, calib.cy + dy)
    model_flow = ideal.flow(omega / gain, model.cx + dx, model.cy + dy)
    if axis < 2:  # at the principal point, exactly; elsewhere to first order
        assert np.allclose(seen[0], model_flow[0], rtol=1e-9, atol=1e-12)
    else:
        assert np.allclose(seen, model_flow, rtol=1e-9)
    assert output_gain({**spec, "pixels": "model"}, calib).tolist() == [1.0, 1.0, 1.0]


def test_the_sensor_window_centres_the_principal_point_without_resampling():
    from spikegyro.events.calib import Calibration
    from spikegyro.stream.predict import event_mapper

    spec = {**SPEC, "sensor": [240, 180], "pixels": "sensor"}
    events = EventArray.from_arrays([0, 5, 200, 239, 300], [0, 3, 100, 179, 250],
                                    [1, 2, 3, 4, 5], [0, 1, 1, 0, 1], 346, 260)  # fmt: skip
    mapped = event_mapper((346, 260), spec, Calibration(300.0, 300.0, 173.4, 129.6), "x")(events)
    # principal point (173.4, 129.6) -> (120, 90): a shift of (53, 40) px, edges dropped
    assert (mapped.width, mapped.height) == (240, 180)
    assert mapped.x.tolist() == [147, 186] and mapped.y.tolist() == [60, 139]
    assert mapped.t.tolist() == [3, 4] and mapped.p.tolist() == [1, 0]


def test_clock_text_is_what_parse_reads():
    for clock in (Clock(), Clock(500, 1000, 20_000), Clock(3, 250, 1500)):
        assert Clock.parse(clock.text) == clock
