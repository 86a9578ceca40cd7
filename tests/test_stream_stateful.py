"""The event-driven stateful network reproduces the batch forward step for step."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from stream_helpers import TinySNN, exact_double, random_events, step_offsets

from spikegyro.events.representations import spike_tensor
from spikegyro.kernel_fit import fit_alpha_kernel, fit_exp_kernel
from spikegyro.snn.kernels import refractory_kernel, srm_kernel
from spikegyro.stream.model import spec_from_model
from spikegyro.stream.stateful import StreamingSNN

H, W = 24, 32


@pytest.mark.parametrize("tau", [1.0, 2.0, 4.0, 8.0])
def test_srm_kernel_is_a_double_pole(tau):
    c, p = fit_alpha_kernel(srm_kernel(tau).numpy())
    assert c == pytest.approx(math.e / tau, rel=1e-5)
    assert p == pytest.approx(math.exp(-1 / tau), rel=1e-6)


@pytest.mark.parametrize(("theta", "tau_r"), [(0.27, 1.0), (0.4, 4.0)])
def test_refractory_kernel_is_a_single_pole(theta, tau_r):
    a, q = fit_exp_kernel(refractory_kernel(theta, tau_r).numpy())
    assert a == pytest.approx(-2 * theta, rel=1e-6)
    assert q == pytest.approx(math.exp(-1 / tau_r), rel=1e-6)


def test_kernels_of_another_shape_are_refused():
    with pytest.raises(ValueError, match="c k p"):
        fit_alpha_kernel(np.array([0.0, 1.0, 0.5, 0.5, 0.1]))
    with pytest.raises(ValueError, match="a q"):
        fit_exp_kernel(np.array([0.0, -1.0, -0.5, -0.4]))


def _batch(model, events, steps, dtype):
    x = spike_tensor(
        events.x, events.y, events.t, events.p, height=H, width=W, t_start_us=0, num_bins=steps
    )
    with torch.no_grad():
        out, spikes = model.forward_with_spikes(torch.from_numpy(x)[None].to(dtype))
    return out[0].T.numpy(), [int(s.sum()) for s in spikes]


def test_stateful_equals_batch_in_double_precision_across_uneven_calls():
    model = exact_double(TinySNN())
    steps = 160
    events = random_events(W, H, steps, rate=0.02, seed=1)
    expected, spike_counts = _batch(model, events, steps, torch.float64)
    assert min(spike_counts) > 100  # every layer is active
    engine = StreamingSNN(spec_from_model(model, (2, H, W), np.float64), dtype=np.float64)
    index, offsets = step_offsets(events, 0, steps)
    outs = []
    for a, b in ((0, 1), (1, 37), (37, 38), (38, 120), (120, steps)):  # state carried over
        outs.append(engine.run(index[offsets[a] : offsets[b]], offsets[a : b + 1] - offsets[a]))
    got = np.concatenate(outs)
    assert engine.spike_counts.tolist() == spike_counts
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_stateful_float32_matches_batch_within_1e4():
    model = TinySNN(seed=3)
    steps = 120
    events = random_events(W, H, steps, rate=0.01, seed=2)
    expected, _ = _batch(model, events, steps, torch.float32)
    engine = StreamingSNN(spec_from_model(model, (2, H, W)))
    got = engine.run(*step_offsets(events, 0, steps))
    scale = np.abs(expected).max()
    assert scale > 0
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4 * scale)


def test_duplicate_events_in_a_bin_count_once():
    model = TinySNN()
    engine = StreamingSNN(spec_from_model(model, (2, H, W)))
    events = random_events(W, H, 40, rate=0.03, seed=4)
    index, offsets = step_offsets(events, 0, 40)
    once = engine.run(index, offsets)
    engine.reset()
    # every event twice, adjacent: the binary input is unchanged
    twice = engine.run(np.repeat(index, 2), offsets * 2)
    np.testing.assert_array_equal(once, twice)


def test_state_returns_to_exact_zero_after_the_kernels_end():
    # One burst, then silence: the batch output is exactly zero once every truncated kernel has
    # passed, and the streaming state is dropped (not just small) by then.
    model = TinySNN()
    engine = StreamingSNN(spec_from_model(model, (2, H, W)))
    events = random_events(W, H, 5, rate=0.2, seed=5)
    steps = 200
    expected, _ = _batch(model, events, steps, torch.float32)
    got = engine.run(*step_offsets(events, 0, steps))
    assert np.abs(expected[:50]).max() > 0
    quiet = np.flatnonzero(np.abs(expected).max(axis=1) > 0)[-1] + 1
    assert quiet < steps
    assert np.all(got[quiet:] == 0.0)
    assert not engine._state.any()  # every pixel went stale and was cleared


def test_snn6_streaming_equals_its_batch_forward():
    # Double precision on both sides, so the comparison is not at the mercy of a potential that
    # lands within float32 rounding of the threshold (a flipped spike moves the output by far
    # more than 1e-4 when layer 5 has a handful of pixels).
    from spikegyro.models.snn6 import SNN6

    torch.manual_seed(0)
    height, width, steps = 64, 72, 100
    model = exact_double(SNN6()).eval()
    events = random_events(width, height, steps, rate=0.01, seed=6)
    x = spike_tensor(events.x, events.y, events.t, events.p, height=height, width=width,
                     t_start_us=0, num_bins=steps)  # fmt: skip
    with torch.no_grad():
        out, spikes = model.forward_with_spikes(torch.from_numpy(x)[None].double())
    expected = out[0].T.numpy()
    engine = StreamingSNN(spec_from_model(model, (2, height, width), np.float64), np.float64)
    index, offsets = step_offsets(events, 0, steps)
    got = np.concatenate([engine.run(index[: offsets[60]], offsets[:61]),
                          engine.run(index[offsets[60]:], offsets[60:] - offsets[60])])  # fmt: skip
    assert engine.spike_counts.tolist() == [int(s.sum()) for s in spikes]
    assert engine.spike_counts[-1] > 0
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_shipped_snn6_at_full_size_streams_its_batch_forward():
    # The trained network at 240x180 on a simulated rotation, double precision on both sides.
    # The engine runs the kernels as exact recursions, so the reference needs exact float64 taps:
    # taps only widened from float32 (``.double()``) are off by up to 6e-8 relative, enough to flip
    # a potential that lands that close to the threshold, which trained layers do (here too).
    from spikegyro.models.registry import load_checkpoint
    from spikegyro.sim.dataset import SimConfig, simulate_sequence
    from spikegyro.stream.model import DEFAULT_CHECKPOINT

    steps = 150
    events = simulate_sequence(SimConfig(duration_ms=steps), 0, seed=0, split="test").events
    t0 = int(events.t[0]) // 1000 * 1000
    x = spike_tensor(events.x, events.y, events.t, events.p, height=180, width=240,
                     t_start_us=t0, num_bins=steps)  # fmt: skip
    index, offsets = step_offsets(events, t0, steps)
    deviations = []
    for exact in (True, False):
        model = load_checkpoint(DEFAULT_CHECKPOINT)[0].eval()
        model = exact_double(model) if exact else model.double()
        with torch.no_grad():
            out, spikes = model.forward_with_spikes(torch.from_numpy(x)[None].double())
        expected = out[0].T.numpy()
        engine = StreamingSNN(spec_from_model(model, (2, 180, 240), np.float64), np.float64)
        first = engine.run(index[: offsets[70]], offsets[:71])
        got = np.concatenate([first, engine.run(index[offsets[70] :], offsets[70:] - offsets[70])])
        if exact:
            assert engine.spike_counts.tolist() == [int(s.sum()) for s in spikes]
            assert min(engine.spike_counts) > 10_000
        deviations.append(np.abs(got - expected).max() / np.abs(expected).max())
    assert deviations[0] < 1e-10
    assert deviations[1] > 1e-6  # widened taps: some spike flipped (this is what exact taps fix)
