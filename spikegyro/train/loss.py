"""The paper's training loss: the time-averaged Euclidean error of the angular velocity; and the
validation metrics a run logs."""

from __future__ import annotations

import math

import numpy as np
import torch

from spikegyro import metrics


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


def validation_metrics(
    prediction: np.ndarray, truth: np.ndarray, start_step: int
) -> dict[str, float]:
    """Loss and the paper's headline numbers on (n, T, 3) rad/s arrays, steps >= start_step.

    The numbers are :mod:`spikegyro.metrics`'s, so validation and ``spikegyro
    evaluate`` agree: ``val_median_rel`` is
    :func:`~spikegyro.metrics.median_relative_error` (NaN when no true speed reaches
    1 deg/s), ``val_mean_err_deg`` the mean Euclidean error in deg/s (the paper's "RMSE") and
    ``val_loss`` the same in rad/s (the training loss's unit).
    A diverged model (a non-finite prediction) scores NaN throughout, which never counts as
    the best validation.
    """
    if not np.isfinite(prediction).all():
        return {"val_loss": math.nan, "val_median_rel": math.nan, "val_mean_err_deg": math.nan}
    mean_deg = metrics.mean_euclidean_error(prediction, truth, start_step)
    median = metrics.median_relative_error(prediction, truth, start_step)
    return {
        "val_loss": math.radians(mean_deg),
        "val_median_rel": math.nan if median is None else median,
        "val_mean_err_deg": mean_deg,
    }
