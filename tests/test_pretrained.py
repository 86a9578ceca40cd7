"""Bundled weights by name, and the shipped models: each loads, and regresses ω on fresh
simulated data far better than the mean."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.errors import InputError
from spikegyro.metrics import mean_euclidean_error, median_relative_error
from spikegyro.models.registry import (
    PRETRAINED_DIR,
    PRETRAINED_SNN6,
    bundled_names,
    load_checkpoint,
    model_card,
    read_checkpoint,
    resolve_checkpoint,
)
from spikegyro.sim.dataset import SimConfig, generate_dataset
from spikegyro.train.data import fixed_windows
from spikegyro.train.infer import predict_windows


@pytest.fixture(scope="module")
def unseen_windows(tmp_path_factory) -> list:
    """Eight 100 ms test windows: the held-out photograph and new procedural panoramas, with a
    seed no shipped model was trained on."""
    root = tmp_path_factory.mktemp("unseen")
    config = SimConfig(duration_ms=200, val_fraction=0.0, test_fraction=0.8)
    generate_dataset(root, 5, seed=97, config=config)
    windows = fixed_windows(root, "test")
    assert len(windows) == 8
    return windows


@pytest.mark.parametrize(
    ("name", "model", "representation"), [("snn6", "snn6", "spikes"), ("ann6", "ann6", "voxel")]
)
def test_shipped_model_beats_the_mean_predictor_on_unseen_scenes(
    unseen_windows, name, model, representation
) -> None:
    net, payload = load_checkpoint(name)
    spec = payload["input"]
    assert (payload["model"], spec["representation"]) == (model, representation)
    assert spec["sensor"] == [240, 180]
    pred = predict_windows(net, payload, unseen_windows).astype(np.float64)  # (n, T, 3)
    gt = np.stack([w.omega for w in unseen_windows])
    mean = np.zeros_like(gt)  # the training data's ω is zero-mean per axis
    rel = median_relative_error(pred, gt)
    # Each window's prediction must follow its own motion: matched to another window's, the
    # same outputs are far worse.
    shuffled = pred[np.roll(np.arange(len(pred)), 1)]
    assert rel < 0.6 * median_relative_error(shuffled, gt)
    # Measured on 320 seed-11 test windows: 0.22 for both; a small split scatters around that.
    assert rel < 0.45, rel
    assert mean_euclidean_error(pred, gt) < 0.5 * mean_euclidean_error(mean, gt)


def test_every_bundled_model_is_a_checkpoint_with_a_model_card() -> None:
    names = bundled_names()
    assert "snn6" in names
    assert names == sorted(p.stem for p in PRETRAINED_DIR.iterdir() if p.suffix == ".pt")
    for name in names:
        card = model_card(name).read_text(encoding="utf-8")
        assert f"`{name}`" in card, f"{name}.md does not name its model"
        payload = read_checkpoint(name)
        assert set(payload) >= {"model", "model_kwargs", "input", "state_dict"}
        # weights only: no optimizer state or other training leftovers in the package
        assert not {"optimizer", "scheduler", "optimizer_state_dict"} & set(payload), name


def test_names_and_paths_resolve_to_the_same_file(tmp_path, monkeypatch) -> None:
    assert resolve_checkpoint("snn6") == PRETRAINED_SNN6
    assert resolve_checkpoint(PRETRAINED_SNN6) == PRETRAINED_SNN6
    own = tmp_path / "mine.pt"
    own.write_bytes(PRETRAINED_SNN6.read_bytes())
    assert resolve_checkpoint(own) == own
    # a bare word in the working folder is a file when no bundled model has that name ...
    monkeypatch.chdir(tmp_path)
    (tmp_path / "weights").write_bytes(b"x")
    assert resolve_checkpoint("weights").name == "weights"
    # ... and the bundled model when one has: ./snn6 names the file
    (tmp_path / "snn6").write_bytes(b"x")
    assert resolve_checkpoint("snn6") == PRETRAINED_SNN6
    assert resolve_checkpoint("./snn6").resolve() == (tmp_path / "snn6").resolve()


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("snn7", "not a bundled model and no such checkpoint file"),
        ("runs/x/best.pt", "no such checkpoint file"),
        (".", "is a folder"),
    ],
)
def test_an_unknown_name_lists_the_bundled_ones(spec, says) -> None:
    with pytest.raises(InputError) as info:
        resolve_checkpoint(spec, "--init")
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"--init {spec}: {says}")
    assert message.endswith(f"one of: {', '.join(bundled_names())}.")


def test_snn6_real_is_the_shipped_weights_on_the_event_clock_and_sensor_pixels() -> None:
    """The card says `snn6-real` is `snn6` untrained further: the same weights, run on the
    event clock it names, reading the sensor's own pixels."""
    import torch

    from spikegyro.events.clock import Clock
    from spikegyro.pretrained import resolve_checkpoint

    real = torch.load(resolve_checkpoint("snn6-real"), weights_only=False)
    base = torch.load(resolve_checkpoint("snn6"), weights_only=False)
    assert real["state_dict"].keys() == base["state_dict"].keys()
    weights = base["state_dict"]
    assert all(torch.equal(real["state_dict"][k], weights[k]) for k in weights)
    assert Clock.from_dict(real["input"]["clock"]) == Clock.parse("events:1000:1-20")
    assert real["input"]["pixels"] == "sensor" and "clock" not in base["input"]
