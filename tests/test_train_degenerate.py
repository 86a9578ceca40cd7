"""Windows with almost nothing in them (no event, one, a few, one polarity, one pixel) go through
every model's data path under every augmentation, in real DataLoader workers; a sample that still
fails names itself in one line (``spikegyro train`` stops with it: see test_train_loop.py)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from spikegyro.events.core import EventArray
from spikegyro.models.registry import build_model
from spikegyro.train.augment import AugmentConfig, reverse_time
from spikegyro.train.data import (
    InputSpec,
    SampleError,
    TrainingSamples,
    Window,
    device_batch,
    encode_window,
    sample_error_line,
)
from spikegyro.train.throughput import train_step

SIZE = 64  # SNN-6 needs at least 63 px for its five unpadded convolutions
WINDOW_MS = 20


def _events(x, y, t, p) -> EventArray:
    return EventArray.from_arrays(
        np.asarray(x, np.int64), np.asarray(y, np.int64), np.asarray(t, np.int64),
        np.asarray(p, np.int64), SIZE, SIZE,
    )  # fmt: skip


def _kinds() -> dict[str, EventArray]:
    rng = np.random.default_rng(1)
    n = 200
    t = np.sort(rng.integers(0, WINDOW_MS * 1000, n))
    last = WINDOW_MS * 1000 - 1
    return {
        "no events": _events([], [], [], []),
        "one event": _events([5], [7], [1500], [1]),
        "one event at the last microsecond": _events([SIZE - 1], [0], [last], [0]),
        "three events": _events([0, 63, 20], [0, 63, 40], [0, 9000, last], [1, 0, 1]),
        "one polarity": _events(rng.integers(0, SIZE, n), rng.integers(0, SIZE, n), t, [1] * n),
        "one pixel": _events([31] * n, [32] * n, t, rng.integers(0, 2, n)),
        "one timestamp": _events(
            rng.integers(0, SIZE, 50),
            rng.integers(0, SIZE, 50),
            [4000] * 50,
            rng.integers(0, 2, 50),
        ),
    }


KINDS = _kinds()

AUGMENTATIONS = {
    "none": AugmentConfig(0.0, 0.0, 0.0),
    "horizontal flip": AugmentConfig(1.0, 0.0, 0.0),
    "vertical flip": AugmentConfig(0.0, 1.0, 0.0),
    "time inversion": AugmentConfig(0.0, 0.0, 1.0),
    "all flips, all events dropped or kept": AugmentConfig(1.0, 1.0, 1.0, keep_min=0.0),
    "aperture": AugmentConfig(0.0, 0.0, 1.0, centre=1.0),
    "noise events": AugmentConfig(0.0, 0.0, 1.0, noise_hz=30.0),
}


@dataclass(frozen=True)
class KindSource:
    """Sample i is window kind i % len(KINDS), with ground truth that turns over the window."""

    def draw(self, rng: np.random.Generator, index: int) -> Window:
        events = list(KINDS.values())[index % len(KINDS)]
        ends = np.arange(1, WINDOW_MS + 1, dtype=np.float32)[:, None]
        omega = np.float32([1.0, -2.0, 0.5]) + 0.01 * ends
        return Window(events, 0, omega, np.float32([1.0, -2.0, 0.5]), "degenerate", index)


@dataclass(frozen=True)
class AugmentOfBatch:
    """Batch b (samples b*len(KINDS) ...) gets the b-th augmentation of AUGMENTATIONS."""

    def __call__(self, window: Window, rng: np.random.Generator) -> Window:
        configs = list(AUGMENTATIONS.values())
        return configs[window.index // len(KINDS) % len(configs)](window, rng)


def _spec(representation: str) -> InputSpec:
    spikes = representation == "spikes"
    output = "per_step" if spikes else "window_mean"
    return InputSpec(representation=representation, sensor=(SIZE, SIZE), window_ms=WINDOW_MS,
                     output=output, num_bins=5, target_ms=10)  # fmt: skip


def _check_content(x: torch.Tensor, window: Window, spec: InputSpec) -> None:
    """What the encoded input must hold, counted from the (augmented) window's events."""
    ev = window.events
    p, y, x_ = (ev.p.astype(np.int64), ev.y.astype(np.int64), ev.x.astype(np.int64))
    if spec.representation == "spikes":
        cells = set(zip(p, y, x_, (ev.t - window.t_start_us) // 1000, strict=True))
        assert int(torch.count_nonzero(x)) == len(cells)
    elif spec.representation == "voxel":  # each event spreads its signed polarity over bins
        assert float(x.sum()) == pytest.approx(float((2 * p - 1).sum()), abs=1e-3)
    else:
        sub = (ev.t - window.t_start_us) // (spec.target_ms * 1000)
        cells = set(zip(sub, p, y, x_, strict=True))
        assert int(torch.count_nonzero(x)) == len(cells)
        assert not len(ev) or float(x.max()) == 1.0  # scaled to the busiest pixel's count


def _model(name: str, spec: InputSpec) -> torch.nn.Module:
    torch.manual_seed(0)
    if name.startswith("snn6"):
        model = build_model("snn6")
        if name.endswith("engine"):
            model.set_surrogate_cut(0.2)
            model.use_event_engine(1)
        return model
    return build_model(name, in_channels=spec.in_channels)


def _loader(representation: str, events: bool) -> tuple[TrainingSamples, DataLoader]:
    """Batch b holds every kind of window, under the b-th augmentation, from a worker process."""
    samples = TrainingSamples(
        KindSource(), _spec(representation), seed=3, augment=AugmentOfBatch(), events=events
    )
    order = range(len(KINDS) * len(AUGMENTATIONS))
    loader = DataLoader(samples, batch_size=len(KINDS), sampler=order, num_workers=1,
                        collate_fn=samples.collate)  # fmt: skip
    return samples, loader


@pytest.mark.parametrize("events", [False, True], ids=["dense", "event lists"])
@pytest.mark.parametrize("representation", ["spikes", "voxel", "frames"])
def test_degenerate_windows_pass_every_data_path_under_every_augmentation(representation, events):
    samples, loader = _loader(representation, events)
    spec = samples.spec
    for b, (inputs, targets) in enumerate(loader):
        x, y = device_batch(inputs, targets, spec, "cpu")
        assert torch.isfinite(x).all() and torch.isfinite(y).all()
        per_window = x.view(len(KINDS), -1, *x.shape[1:])
        for i in range(len(KINDS)):
            window = samples.window(b * len(KINDS) + i)
            expected = encode_window(window, spec)
            assert torch.equal(per_window[i].reshape(expected.shape), expected)
            _check_content(expected, window, spec)


@pytest.mark.parametrize(
    ("representation", "model"),
    [("spikes", "snn6"), ("spikes", "snn6 event engine"), ("voxel", "ann6"),
     ("frames", "ann6"), ("voxel", "resnet50"), ("frames", "resnet50")],
)  # fmt: skip
def test_every_model_trains_on_a_batch_of_degenerate_windows(representation, model):
    """A training step on one batch of every kind of window (time-inverted, flipped, thinned),
    through the data path the model trains on: finite loss, finite gradients."""
    sparse = model.endswith("engine")
    samples, loader = _loader(representation, events=sparse)
    batch = list(AUGMENTATIONS).index("all flips, all events dropped or kept")
    inputs, targets = next(b for i, b in enumerate(loader) if i == batch)
    x, y = device_batch(inputs, targets, samples.spec, "cpu", sparse)
    net = _model(model, samples.spec)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
    loss = train_step(net, optimizer, x, y, loss_start_step=5)
    assert torch.isfinite(loss)
    for param in net.parameters():
        assert param.grad is None or torch.isfinite(param.grad).all()


def test_a_reversed_one_event_window_is_a_plain_array():
    """The cause of a crash seen in a long run: a one-element reversed view counts as contiguous
    for NumPy, so np.ascontiguousarray kept its negative stride and torch.from_numpy refused it."""
    window = KindSource().draw(np.random.default_rng(0), 1)
    reversed_ = reverse_time(window)
    assert all(a.strides[0] > 0 for a in (reversed_.events.x, reversed_.events.y))
    view = np.arange(3)[::-1][:1]  # the same shape of array, as any other caller could pass
    assert view.strides[0] < 0 and np.ascontiguousarray(view).strides[0] < 0
    for rep in ("spikes", "voxel", "frames"):
        flipped = replace(window, events=replace(window.events, x=view.astype(np.int16)))
        assert encode_window(flipped, _spec(rep)).isfinite().all()


class _Boom(RuntimeError):
    pass


def test_a_failing_sample_names_itself_in_one_line_from_a_worker():
    samples = TrainingSamples(KindSource(), _spec("voxel"), seed=3, augment=_fail_on(9))
    loader = DataLoader(samples, batch_size=4, sampler=range(12), num_workers=1)
    with pytest.raises(SampleError) as info:
        list(loader)
    assert "Traceback" in str(info.value)  # the worker's, which the one line leaves out
    line = sample_error_line(info.value)
    assert line == "training sample 9 (seed 3): _Boom: no window 9 here"


@dataclass(frozen=True)
class _fail_on:
    index: int

    def __call__(self, window: Window, rng: np.random.Generator) -> Window:
        if window.index == self.index:
            raise _Boom(f"no window {window.index}\nhere")
        return window
