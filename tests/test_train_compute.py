"""``train --compute sparse|dense``: the event-driven engine in the training loop."""

from __future__ import annotations

import pytest
import torch
from test_train_loop import dataset, state_of, tiny_config  # noqa: F401 (fixture)

from spikegyro.errors import InputError
from spikegyro.models.snn6 import SNN6
from spikegyro.train.distributed import DistContext
from spikegyro.train.loop import configure_compute, train


def test_sparse_and_dense_runs_share_checkpoints_and_freeze(dataset, tmp_path):  # noqa: F811
    """A sparse run resumes a dense one (same weights, same optimizer state), frozen layers stay
    fixed, and the grid readout trains on the engine."""
    dense = train(tiny_config(dataset, tmp_path, compute="dense", iterations=2, val_every=2),
                  progress=False)  # fmt: skip
    assert dense.compute == "dense"
    resumed = train(tiny_config(dataset, tmp_path, compute="sparse", iterations=3, val_every=3),
                    resume=True, progress=False)  # fmt: skip
    assert resumed.compute == "sparse" and resumed.steps == 3
    grid = train(tiny_config(dataset, tmp_path / "g", model="snn6-grid", freeze=2,
                             init=str(tmp_path / "last.pt"), iterations=1, val_every=1),
                 progress=False)  # fmt: skip
    assert grid.compute == "sparse"  # the CPU default
    before, after = state_of(tmp_path / "last.pt"), state_of(tmp_path / "g" / "last.pt")
    assert torch.equal(before["conv1.weight"], after["conv1.weight"])
    assert not torch.equal(before["conv3.weight"], after["conv3.weight"])


def test_the_engine_trains_on_event_batches_as_on_dense_ones(dataset, tmp_path):  # noqa: F811
    """With --compute sparse the loop ships events and bins them into a sparse tensor: the
    engine reads the same spikes as from the dense tensor, so the runs end with the same
    weights, bit for bit."""
    runs = {}
    for path in ("auto", "dense"):
        config = tiny_config(dataset, tmp_path / path, compute="sparse", data_path=path,
                             iterations=2, val_every=2, threads=2)  # fmt: skip
        runs[path] = train(config, progress=False)
    assert (runs["auto"].data_path, runs["dense"].data_path) == ("events", "dense")
    events, dense = (
        state_of(tmp_path / "auto" / "last.pt"),
        state_of(tmp_path / "dense" / "last.pt"),
    )
    assert events.keys() == dense.keys()
    for name, tensor in dense.items():
        assert torch.equal(events[name], tensor), name
    assert runs["auto"].last_loss == runs["dense"].last_loss


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"compute": "fast"}, "--compute fast"),
        ({"compute": "sparse", "model": "ann6"}, "the ANNs use --compute dense"),
        ({"compute": "sparse", "device": "cuda"}, "runs on the CPU"),
        ({"compute": "sparse", "surrogate_cut": 0.01}, "cut above 0.0357"),
        ({"surrogate_cut": 1.5}, "must lie in"),
    ],
)
def test_bad_compute_options_are_one_line_errors(dataset, tmp_path, overrides, message):  # noqa: F811
    with pytest.raises(InputError, match=message) as error:
        tiny_config(dataset, tmp_path, **overrides)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("compute", ["sparse", "dense"])
def test_the_engine_threads_own_the_cores(dataset, tmp_path, compute):  # noqa: F811
    """With the event engine, its threads run the batch and torch keeps one thread (its
    OpenMP workers would spin on the engine's cores); the dense path keeps torch's threads."""
    config = tiny_config(dataset, tmp_path, compute=compute, threads=2)
    model = SNN6()
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert configure_compute(model, config, DistContext()) == compute
        engine = model.event_engine
        if compute == "sparse":
            assert engine is not None and engine.threads == 2
            assert torch.get_num_threads() == 1
        else:
            assert engine is None and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
