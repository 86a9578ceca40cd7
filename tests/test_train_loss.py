"""The training loss against a hand computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spikegyro.train.loss import angular_velocity_loss, validation_metrics


def test_loss_is_the_mean_euclidean_error_over_late_steps():
    target = torch.zeros(2, 3, 4)
    prediction = torch.zeros(2, 3, 4)
    # sample 0: errors (3, 4, 0) -> 5 at step 2, (0, 0, 2) -> 2 at step 3
    prediction[0, :, 2] = torch.tensor([3.0, 4.0, 0.0])
    prediction[0, :, 3] = torch.tensor([0.0, 0.0, 2.0])
    # sample 1: error (1, 2, 2) -> 3 at step 3; a huge error at step 1 must not count
    prediction[1, :, 3] = torch.tensor([1.0, 2.0, 2.0])
    prediction[1, :, 1] = 100.0
    loss = angular_velocity_loss(prediction, target, start_step=2)
    assert float(loss) == pytest.approx((5 + 2 + 0 + 3) / 4)
    all_steps = angular_velocity_loss(prediction, target, start_step=0)
    assert float(all_steps) == pytest.approx((5 + 2 + 3 + 100 * math.sqrt(3)) / 8)


def test_window_means_count_every_window_and_gradients_flow():
    prediction = torch.tensor([[1.0, 2.0, 2.0], [0.0, 0.0, 0.0]], requires_grad=True)
    target = torch.tensor([[0.0, 0.0, 0.0], [0.0, 3.0, 4.0]])
    loss = angular_velocity_loss(prediction, target)
    assert loss.item() == pytest.approx((3 + 5) / 2)
    loss.backward()
    # d/dp of |p - t| / 2 is the unit error vector / 2
    torch.testing.assert_close(prediction.grad[0], torch.tensor([1.0, 2.0, 2.0]) / 3 / 2)


def test_shape_mismatch_and_bad_start_are_rejected():
    with pytest.raises(ValueError, match="prediction"):
        angular_velocity_loss(torch.zeros(1, 3, 10), torch.zeros(1, 10, 3))
    with pytest.raises(ValueError, match="start_step"):
        angular_velocity_loss(torch.zeros(1, 3, 10), torch.zeros(1, 3, 10), start_step=10)


def test_validation_metrics_skip_early_steps_and_near_zero_truth():
    truth = np.zeros((2, 4, 3))
    truth[:, :, 0] = np.radians([[100.0, 100.0, 100.0, 0.5], [100.0, 50.0, 50.0, 50.0]])
    prediction = truth.copy()
    prediction[0, :, 1] = np.radians(10.0)  # 10 deg/s off everywhere in window 0
    prediction[1, :, 2] = np.radians(20.0)  # 20 deg/s off in window 1
    got = validation_metrics(prediction, truth, start_step=1)
    # steps 1..3: errors 10, 10, 10 and 20, 20, 20 deg/s
    assert got["val_mean_err_deg"] == pytest.approx(15.0)
    assert got["val_loss"] == pytest.approx(np.radians(15.0))
    # ratios 0.1, 0.1 (the 0.5 deg/s truth left out) and 0.4, 0.4, 0.4
    assert got["val_median_rel"] == pytest.approx(0.4)
