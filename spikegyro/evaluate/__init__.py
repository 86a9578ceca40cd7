"""Metrics, per-speed bins, figures and reports.

``run_evaluation`` scores a model and the mean predictor on a dataset split and writes
metrics.json, predictions.npz, figures and a report; ``compare_runs`` puts several such runs side
by side. The pure metric functions live in :mod:`.metrics` and :mod:`.bins`.
"""

from spikegyro.evaluate.commands import run_evaluation
from spikegyro.evaluate.compare import compare_runs

__all__ = ["compare_runs", "run_evaluation"]
