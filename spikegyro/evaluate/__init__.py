"""Metrics, per-speed bins, figures and reports.

``run_evaluation`` scores a model and the mean predictor on a dataset split and writes
metrics.json, predictions.npz, figures and a report (:mod:`.simulated`); ``compare_runs`` puts
several such runs side by side; ``run_real_evaluation`` scores SNN-6, CMax and the mean
predictor against a gyro on a real recording (:mod:`.real`). The paper's metrics are
:mod:`spikegyro.metrics` (one definition for evaluation, training validation and ``predict``,
below all three), the per-speed bins :mod:`.bins`, the gyro-events clock offset fit
:mod:`.offset`.
"""

from typing import Any

_LAZY = {
    "compare_runs": "spikegyro.evaluate.compare",
    "run_evaluation": "spikegyro.evaluate.simulated",
    "run_real_evaluation": "spikegyro.evaluate.real",
}

__all__ = ["compare_runs", "run_evaluation", "run_real_evaluation"]


def __getattr__(name: str) -> Any:
    # The drivers import torch, matplotlib and the models: imported on first use, so that the
    # light modules of this package (bins, offset) do not pay for them.
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'spikegyro.evaluate' has no attribute '{name}'")
