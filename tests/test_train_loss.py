"""The training loss against a hand computation."""

from __future__ import annotations

import math

import pytest
import torch

from spikegyro.train.loss import angular_velocity_loss


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
