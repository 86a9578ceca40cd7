"""The frame path trains: ResNet-50 (A) and ANN-6 on accumulated event frames overfit a small
fixed set of simulated windows, through the training data path (``encode_window`` /
``encode_target``), the registry's models and the training loss, scored in eval mode as
``spikegyro evaluate`` scores them.

Slow: 64 windows of 20 ms, ResNet-50 at 120x90; several minutes on two cores.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spikegyro.events.io import read_recording
from spikegyro.models.registry import build_model
from spikegyro.sim.dataset import generate_dataset
from spikegyro.train.data import (
    InputSpec,
    Window,
    encode_target,
    encode_window,
    sequence_windows,
    split_files,
)
from spikegyro.train.loss import angular_velocity_loss

pytestmark = pytest.mark.slow

WINDOWS = 64
WINDOW_MS = 20  # one accumulated frame per window, the ANNs' target window


@pytest.fixture(scope="module")
def windows(tmp_path_factory) -> list[Window]:
    """64 windows of 20 ms from 8 simulated sequences, 8 spread over each."""
    root = tmp_path_factory.mktemp("frames-data")
    generate_dataset(root, 10, seed=5)
    picked = []
    for path in split_files(root, "train"):
        picked += sequence_windows(read_recording(path), WINDOW_MS)[2::3][: WINDOWS // 8]
    assert len(picked) == WINDOWS
    return picked


def median_relative_error(prediction: torch.Tensor, target: torch.Tensor) -> float:
    """Median over windows of ‖ω̂ − ω‖ / ‖ω‖ (the paper's relative error, one step each)."""
    error = (prediction - target).norm(dim=1) / target.norm(dim=1)
    return float(np.median(error.numpy()))


@pytest.mark.parametrize(
    ("model_name", "scale", "steps", "lr"),
    [("ann6", 1.0, 120, 1e-3), ("resnet50", 0.5, 100, 1e-3)],
)
def test_the_frame_path_overfits_a_fixed_set(windows, model_name, scale, steps, lr) -> None:
    torch.manual_seed(0)
    spec = InputSpec.for_representation(
        "frames", sensor=(240, 180), scale=scale, window_ms=WINDOW_MS, target_ms=WINDOW_MS
    )
    frames = torch.cat([encode_window(w, spec) for w in windows])  # (64, 2, H, W) in [0, 1]
    omega = torch.cat([encode_target(w, spec) for w in windows])  # (64, 3) rad/s
    model = build_model(model_name, in_channels=spec.in_channels)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)

    def scored() -> float:
        model.eval()
        with torch.no_grad():
            error = median_relative_error(model(frames), omega)
        model.train()
        return error

    assert scored() > 0.8  # untrained: about the mean predictor's 1.0
    for _ in range(steps):
        optimizer.zero_grad()
        loss = angular_velocity_loss(model(frames), omega)
        loss.backward()
        optimizer.step()
    assert scored() < 0.3
