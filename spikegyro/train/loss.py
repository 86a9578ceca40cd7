"""The paper's training loss: the time-averaged Euclidean error of the angular velocity."""

from __future__ import annotations

import torch


def euclidean_error(prediction: torch.Tensor, target: torch.Tensor, dim: int) -> torch.Tensor:
    """‖prediction − target‖₂ along ``dim`` (the xyz axis), in the inputs' unit (rad/s)."""
    return (prediction - target).pow(2).sum(dim=dim).sqrt()


def angular_velocity_loss(
    prediction: torch.Tensor, target: torch.Tensor, start_step: int = 50
) -> torch.Tensor:
    """Mean Euclidean error over samples and the steps ``k >= start_step`` (rad/s).

    Args:
        prediction: (N, 3, T) ω per step (an SNN's output) or (M, 3) window means (an ANN's).
        target: same shape, rad/s.
        start_step: first step counted for per-step outputs: the paper discards the first
            50 ms, during which the network has not yet seen enough events. Window means have
            no time axis and are all counted.
    """
    if prediction.shape != target.shape:
        raise ValueError(f"prediction {tuple(prediction.shape)} vs target {tuple(target.shape)}")
    error = euclidean_error(prediction, target, dim=1)
    if prediction.dim() == 3:
        if not 0 <= start_step < prediction.shape[-1]:
            raise ValueError(f"start_step {start_step} outside 0..{prediction.shape[-1] - 1}")
        error = error[..., start_step:]
    return error.mean()
