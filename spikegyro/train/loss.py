"""The paper's training loss: the time-averaged Euclidean error of the angular velocity; and the
validation metrics a run logs."""

from __future__ import annotations

import numpy as np
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


def validation_metrics(
    prediction: np.ndarray, truth: np.ndarray, start_step: int
) -> dict[str, float]:
    """Loss and the paper's headline numbers on (n, T, 3) rad/s arrays, steps >= start_step.

    ``val_median_rel`` is the median of ‖ω − ω̂‖/‖ω̂‖ over (window, step) pairs with
    ‖ω̂‖ >= 1 deg/s; ``val_mean_err_deg`` the mean Euclidean error in deg/s (the paper's "RMSE").
    """
    err = np.linalg.norm(prediction - truth, axis=-1)[:, start_step:]
    norm = np.linalg.norm(truth, axis=-1)[:, start_step:]
    valid = norm >= np.radians(1.0)
    rel = err[valid] / norm[valid]
    return {
        "val_loss": float(err.mean()),
        "val_median_rel": float(np.median(rel)) if rel.size else float("nan"),
        "val_mean_err_deg": float(np.degrees(err.mean())),
    }
