"""The fast paths of the streaming runtime change nothing: blocks, the two-core pipeline, the
input-map choice, the cycle profile, and the torch-free (cached) loading of a checkpoint."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch
from stream_helpers import TinySNN, exact_double, random_events, step_offsets

from spikegyro.events.representations import spike_tensor
from spikegyro.models.registry import PRETRAINED_SNN6, save_checkpoint
from spikegyro.models.snn6 import SNN6
from spikegyro.stream.model import (
    DEFAULT_CHECKPOINT,
    load_streaming_model,
    load_streaming_spec,
    spec_cache_dir,
    spec_from_model,
)
from spikegyro.stream.stateful import PROFILE_KINDS, StreamingSNN, _kx_order, _target_table

H, W, STEPS = 24, 32, 150


@pytest.fixture(scope="module")
def spec():
    return spec_from_model(TinySNN(seed=3), (2, H, W))


@pytest.fixture(scope="module")
def stream():
    return step_offsets(random_events(W, H, STEPS, rate=0.015, seed=8), 0, STEPS)


def _calls(engine, index, offsets, cuts):
    """Run the steps in calls that end at ``cuts``; the concatenated readout."""
    outs, a = [], 0
    for b in [*cuts, len(offsets) - 1]:
        outs.append(engine.run(index[offsets[a] : offsets[b]], offsets[a : b + 1] - offsets[a]))
        a = b
    return np.concatenate(outs)


def test_one_step_calls_equal_one_long_call_for_any_block(spec, stream):
    index, offsets = stream
    reference = StreamingSNN(spec, block_steps=1)
    expected = _calls(reference, index, offsets, list(range(1, STEPS)))  # one ms per call
    assert np.abs(expected).max() > 0 and reference.spike_counts.min() > 50
    for block in (3, 8, 64):
        engine = StreamingSNN(spec, block_steps=block)
        np.testing.assert_array_equal(engine.run(index, offsets), expected)
        np.testing.assert_array_equal(engine.spike_counts, reference.spike_counts)


@pytest.mark.parametrize(("kh", "kw", "stride"), [(3, 3, 1), (3, 3, 2), (2, 5, 3), (5, 4, 2)])
def test_scatter_tables_reach_exactly_the_windows_holding_each_input_pixel(kh, kw, stride):
    hin, win = 13, 17
    hout, wout = (hin - kh) // stride + 1, (win - kw) // stride + 1
    tab = _target_table(hin, win, hout, wout, kh, kw, stride)
    oy0, oy1, ox0, ox1, place = np.split(tab, np.cumsum([hin, hin, win, win]))
    order = _kx_order(kw, stride)
    assert sorted(order) == list(range(kw))
    for i in range(hin):  # brute force: output rows o with o * stride <= i < o * stride + kh
        assert list(range(oy0[i], oy1[i] + 1)) == [
            o for o in range(hout) if 0 <= i - o * stride < kh
        ]
    for i in range(win):
        reach = [o for o in range(wout) if 0 <= i - o * stride < kw]
        assert list(range(ox0[i], ox1[i] + 1)) == reach
        # the span of weights read for output pixels ox0.. holds their kernel columns, in order
        span = order[place[i] : place[i] + len(reach)]
        assert list(span) == [i - o * stride for o in reach]


def test_bridging_idle_pixels_changes_no_bit():
    # sparse input: live pixels come in short runs with idle ones (some just expired) between
    events = random_events(W, H, STEPS, rate=0.002, seed=4)
    index, offsets = step_offsets(events, 0, STEPS)
    unbridged = StreamingSNN(spec_from_model(TinySNN(seed=3), (2, H, W)), run_gap=0)
    expected = unbridged.run(index, offsets)
    assert unbridged.spike_counts.min() > 0
    for gap in (1, 3, 64):
        bridged = StreamingSNN(unbridged.spec, run_gap=gap)
        np.testing.assert_array_equal(bridged.run(index, offsets), expected)
        np.testing.assert_array_equal(bridged.spike_counts, unbridged.spike_counts)
        np.testing.assert_array_equal(bridged._state, unbridged._state)  # rounding residues too


@pytest.mark.parametrize("block", [1, 4, 16])
def test_two_thread_pipeline_equals_one_thread(spec, stream, block):
    index, offsets = stream
    single = StreamingSNN(spec)
    expected = single.run(index, offsets)
    piped = StreamingSNN(spec, threads=2, block_steps=block)
    got = _calls(piped, index, offsets, [5, 6, 77])  # state and ring slots carried across calls
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(piped.spike_counts, single.spike_counts)
    assert 1 <= piped._split() < len(spec.layers)


def test_the_split_may_move_both_ways_within_a_call(spec, stream, monkeypatch):
    # layers handed to the second stage at once, and taken back after waiting for it
    index, offsets = stream
    expected = StreamingSNN(spec).run(index, offsets)
    piped = StreamingSNN(spec, threads=2, block_steps=2)
    splits = iter([1, 2, 2, 1, 2, 1, 1, 2] * 20)
    asked = []
    monkeypatch.setattr(piped, "_split", lambda cycles=None: asked.append(1) or next(splits))
    np.testing.assert_array_equal(piped.run(index, offsets), expected)
    assert len(asked) > 8  # the call's own split, then one every RESPLIT_BLOCKS blocks


def test_pipeline_balances_the_profiled_work(spec):
    piped = StreamingSNN(spec, threads=2)
    piped._cycles[:] = 0
    piped._cycles[0, 3] = 10  # layer 1 is the heaviest by far: alone in the first stage
    piped._cycles[1, 0] = piped._cycles[2, 0] = 3
    assert piped._split() == 1
    piped._cycles[2, 0] = 30  # now layer 3 is: layers 1 and 2 go first
    assert piped._split() == 2
    piped.reset()  # a new recording: the profile restarts, the balance is remembered
    assert not piped.profile().any() and piped._split() == 2


@pytest.mark.parametrize("maps", [(False, False, False), (True, True, True)])
def test_input_maps_or_tail_scatter_both_equal_the_batch_forward(maps):
    model = exact_double(TinySNN())
    events = random_events(W, H, STEPS, rate=0.02, seed=1)
    x = spike_tensor(events.x, events.y, events.t, events.p, height=H, width=W, t_start_us=0,
                     num_bins=STEPS)  # fmt: skip
    with torch.no_grad():
        out, spikes = model.forward_with_spikes(torch.from_numpy(x)[None].double())
    expected = out[0].T.numpy()
    engine = StreamingSNN(spec_from_model(model, (2, H, W), np.float64), np.float64,
                          input_maps=maps)  # fmt: skip
    got = _calls(engine, *step_offsets(events, 0, STEPS), [40, 41, 100])
    assert engine.spike_counts.tolist() == [int(s.sum()) for s in spikes]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_profile_accounts_for_the_run(spec, stream):
    engine = StreamingSNN(spec)
    engine.run(*stream)  # compiled
    engine.reset()
    start = time.perf_counter()
    engine.run(*stream)
    wall = time.perf_counter() - start
    profile = engine.profile()
    assert profile.shape == (len(spec.layers) + 1, len(PROFILE_KINDS))
    if profile.sum() == 0:
        pytest.skip("no cycle counter on this CPU")
    assert (profile[:-1, 0] > 0).all() and (profile[:-1, 3] > 0).all()
    assert (profile >= 0).all() and profile.sum() <= 1.2 * wall


def _checkpoint(path, seed):
    torch.manual_seed(seed)
    spec = {"representation": "spikes", "sensor": [80, 64], "scale": 1.0, "output": "per_step"}
    return save_checkpoint(path, SNN6(), name="snn6", model_kwargs={}, input_spec=spec)


def test_cached_spec_equals_the_torch_loaded_one(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIKEGYRO_CACHE", str(tmp_path / "cache"))
    assert spec_cache_dir() == tmp_path / "cache"
    assert DEFAULT_CHECKPOINT == PRETRAINED_SNN6
    ckpt = _checkpoint(tmp_path / "a.pt", 0)
    derived, _ = load_streaming_spec(ckpt)  # through torch, then cached
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 1
    cached, meta_cached = load_streaming_spec(ckpt)
    from spikegyro.models.registry import load_checkpoint

    model, payload = load_checkpoint(ckpt)
    reference = spec_from_model(model, (2, 64, 80))
    for spec in (derived, cached):
        assert spec.input_shape == reference.input_shape
        for got, want in zip(spec.layers, reference.layers, strict=True):
            np.testing.assert_array_equal(got.weight, want.weight)
            np.testing.assert_array_equal(got.srm_kernel, want.srm_kernel)
            np.testing.assert_array_equal(got.ref_kernel, want.ref_kernel)
            assert (got.stride, got.theta) == (want.stride, want.theta)
        np.testing.assert_array_equal(spec.fc_weight, reference.fc_weight)
        np.testing.assert_array_equal(spec.out_kernel, reference.out_kernel)
    assert meta_cached["input"] == payload["input"] and meta_cached["model"] == "snn6"
    # other weights at the same path: a new digest, so the cache is not reused
    _checkpoint(tmp_path / "a.pt", 1)
    other, _ = load_streaming_spec(ckpt)
    assert not np.array_equal(other.layers[0].weight, reference.layers[0].weight)
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2


def test_a_cached_checkpoint_loads_and_runs_without_torch(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIKEGYRO_CACHE", str(tmp_path / "cache"))
    ckpt = _checkpoint(tmp_path / "b.pt", 2)
    engine, _ = load_streaming_model(ckpt)
    index, offsets = step_offsets(random_events(80, 64, 30, rate=0.01, seed=1), 0, 30)
    np.save(tmp_path / "index.npy", index)
    np.save(tmp_path / "offsets.npy", offsets)
    np.save(tmp_path / "expected.npy", engine.run(index, offsets))
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        sys.modules["torch"] = None  # any import of torch now fails
        from spikegyro.stream.model import load_streaming_model
        engine, meta = load_streaming_model({str(ckpt)!r})
        got = engine.run(np.load({str(tmp_path / "index.npy")!r}),
                         np.load({str(tmp_path / "offsets.npy")!r}))
        assert np.array_equal(got, np.load({str(tmp_path / "expected.npy")!r}))
        print(meta["model"])
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "snn6"
