"""Metrics, per-speed bins, figures and reports.

``run_evaluation`` scores a model and the mean predictor on a dataset split and writes
metrics.json, predictions.npz, figures and a report; ``compare_runs`` puts several such runs side
by side; ``run_real_evaluation`` scores SNN-6, CMax and the mean predictor against a gyro on a
real recording (:mod:`.real`). The pure metric functions live in :mod:`.metrics` and
:mod:`.bins`, the gyro-events clock offset fit in :mod:`.offset`.
"""

from spikegyro.evaluate.commands import run_evaluation
from spikegyro.evaluate.compare import compare_runs
from spikegyro.evaluate.real import run_real_evaluation

__all__ = ["compare_runs", "run_evaluation", "run_real_evaluation"]
