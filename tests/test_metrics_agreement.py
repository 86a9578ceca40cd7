"""One definition of the paper's metrics: evaluation (``spikegyro.metrics``), training
validation (``spikegyro.train.loss.validation_metrics``) and the streaming scores of ``spikegyro
predict`` give the same numbers on the same predictions."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro import metrics
from spikegyro.train.loss import validation_metrics


def _hand_case() -> tuple[np.ndarray, np.ndarray]:
    """Two windows of 4 steps, scored from step 1: errors 10, 10, 10 and 20, 20, 20 deg/s;
    relative errors 0.1, 0.1 (a 0.5 deg/s truth left out) and 0.4, 0.4, 0.4."""
    truth = np.zeros((2, 4, 3))
    truth[:, :, 0] = np.radians([[100.0, 100.0, 100.0, 0.5], [100.0, 50.0, 50.0, 50.0]])
    prediction = truth.copy()
    prediction[0, :, 1] = np.radians(10.0)
    prediction[1, :, 2] = np.radians(20.0)
    return prediction, truth


def _random_case(seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    truth = np.radians(rng.laplace(0, 107, (6, 100, 3)))
    truth[0, 60:70] = 0.0  # steps under 1 deg/s, left out of the relative error
    prediction = (truth + np.radians(rng.normal(0, 40, truth.shape))).astype(np.float32)
    return prediction, truth


def test_hand_computed_values():
    pred, gt = _hand_case()
    s = metrics.summary(pred, gt, start=1)
    assert s["mean_euclidean_error_deg_s"] == pytest.approx(15.0)
    assert s["rmse_deg_s"] == pytest.approx(np.sqrt((3 * 10**2 + 3 * 20**2) / 6))
    assert s["median_relative_error"] == pytest.approx(0.4)
    assert (s["n_pairs"], s["n_pairs_relative"]) == (6, 5)
    v = validation_metrics(pred, gt, start_step=1)
    assert v["val_mean_err_deg"] == pytest.approx(15.0)
    assert v["val_loss"] == pytest.approx(np.radians(15.0))
    assert v["val_median_rel"] == pytest.approx(0.4)


@pytest.mark.parametrize("case", [_hand_case, _random_case])
def test_training_validation_equals_evaluation(case):
    pred, gt = case()
    start = 1 if case is _hand_case else metrics.EVAL_START_STEP
    s = metrics.summary(pred, gt, start=start)
    v = validation_metrics(pred, gt, start)
    assert v["val_median_rel"] == s["median_relative_error"]
    assert v["val_mean_err_deg"] == s["mean_euclidean_error_deg_s"]
    assert v["val_loss"] == pytest.approx(np.radians(s["mean_euclidean_error_deg_s"]), rel=1e-15)


def test_validation_of_a_diverged_model_is_nan_and_of_still_truth_has_no_median():
    pred, gt = _random_case()
    pred[2, 70] = np.nan
    assert all(np.isnan(x) for x in validation_metrics(pred, gt, 50).values())
    still = validation_metrics(np.ones((1, 60, 3)), np.zeros((1, 60, 3)), 50)
    assert np.isnan(still["val_median_rel"])
    assert still["val_mean_err_deg"] == pytest.approx(np.degrees(np.sqrt(3)))


def test_streaming_scores_equal_evaluation():
    """``spikegyro predict``'s running scores (bounded memory: sums and a log histogram of the
    relative error at 0.1 % resolution) against the evaluation metrics on the same rows."""
    from spikegyro.stream.predict import ErrorStats

    pred, gt = _random_case()
    rows_pred, rows_gt = pred.reshape(-1, 3).astype(np.float64), gt.reshape(-1, 3)
    stats = ErrorStats()
    for a in range(0, len(rows_gt), 137):  # in chunks, as a stream arrives
        stats.add(rows_pred[a : a + 137], rows_gt[a : a + 137])
    got = stats.summary()
    s = metrics.summary(rows_pred[None], rows_gt[None], start=0)
    assert got["samples"] == s["n_pairs"]
    assert got["mean_error_deg_s"] == pytest.approx(s["mean_euclidean_error_deg_s"], rel=1e-12)
    assert got["rmse_deg_s"] == pytest.approx(s["rmse_deg_s"], rel=1e-12)
    for key, axis in zip("xyz", metrics.AXES, strict=True):
        per_axis = s["per_axis"][axis]
        assert got[f"rmse_{key}_deg_s"] == pytest.approx(per_axis["rmse_deg_s"], rel=1e-12)
        assert got[f"mae_{key}_deg_s"] == pytest.approx(per_axis["mean_abs_error_deg_s"], rel=1e-12)
    # The histogram's bins are 10^0.001 apart: its median is within 0.25 % of the exact one.
    assert got["median_relative_error"] == pytest.approx(s["median_relative_error"], rel=2.5e-3)


def test_the_metrics_import_without_torch():
    """``spikegyro predict`` scores with these metrics and must start without torch."""
    import subprocess
    import sys

    code = "import sys, spikegyro.metrics; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
