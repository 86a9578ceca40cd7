"""Metrics, speed bins and the mean predictor against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spikegyro import metrics
from spikegyro.baselines.mean import mean_predictions, training_mean_omega
from spikegyro.errors import InputError
from spikegyro.evaluate import bins
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording


def windows(pred_deg: list, gt_deg: list, settle: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """(n, settle + k, 3) rad/s arrays whose evaluated steps are the given deg/s rows; the
    settling steps hold a wildly wrong prediction that must not count."""
    pred = np.radians(np.asarray(pred_deg, dtype=np.float64))
    gt = np.radians(np.asarray(gt_deg, dtype=np.float64))
    n = pred.shape[0]
    junk_pred = np.full((n, settle, 3), 1e3)
    junk_gt = np.zeros((n, settle, 3))
    return np.concatenate([junk_pred, pred], 1), np.concatenate([junk_gt, gt], 1)


def test_mean_euclidean_error_and_true_rmse():
    # Window 0: errors of norm 3 and 5 deg/s; window 1: 4 and 0 deg/s.
    pred, gt = windows(
        [[[3, 0, 0], [3, 4, 0]], [[0, 0, 104], [7, 8, 9]]],
        [[[0, 0, 0], [0, 0, 0]], [[0, 0, 100], [7, 8, 9]]],
    )
    assert metrics.mean_euclidean_error(pred, gt) == pytest.approx((3 + 5 + 4 + 0) / 4)
    assert metrics.rmse(pred, gt) == pytest.approx(math.sqrt((9 + 25 + 16 + 0) / 4))
    per_axis = metrics.axis_metrics(pred, gt)
    assert per_axis["tilt"]["mean_abs_error_deg_s"] == pytest.approx((3 + 3) / 4)
    assert per_axis["pan"]["rmse_deg_s"] == pytest.approx(math.sqrt(16 / 4))
    assert per_axis["roll"]["rmse_deg_s"] == pytest.approx(math.sqrt(16 / 4))


def test_median_relative_error_excludes_slow_pairs_below_one_deg_per_s():
    pred, gt = windows(
        [[[12, 0, 0], [100, 0, 0], [0, 1.5, 0], [0, 0, -8]]],
        [[[10, 0, 0], [0.5, 0, 0], [0, 1.0, 0], [0, 0, -10]]],
    )
    # Relative errors 0.2, (excluded: 0.5 deg/s), 0.5 (exactly 1 deg/s is kept), 0.2.
    np.testing.assert_allclose(metrics.relative_errors(pred, gt), [0.2, 0.5, 0.2])
    assert metrics.median_relative_error(pred, gt) == pytest.approx(0.2)
    s = metrics.summary(pred, gt)
    assert (s["n_pairs"], s["n_pairs_relative"]) == (4, 3)


def test_median_relative_error_even_count_and_all_excluded():
    pred, gt = windows([[[11, 0, 0], [13, 0, 0], [12, 0, 0], [19, 0, 0]]], [[[10, 0, 0]] * 4])
    assert metrics.median_relative_error(pred, gt) == pytest.approx((0.2 + 0.3) / 2)
    pred, gt = windows([[[5, 0, 0]]], [[[0.2, 0.3, 0]]])
    assert metrics.median_relative_error(pred, gt) is None
    assert metrics.summary(pred, gt)["median_relative_error"] is None


def test_signed_axis_relative_errors():
    pred, gt = windows([[[12, -25, 3]]], [[[10, -20, 0.5]]])
    tilt, pan, roll = metrics.axis_relative_errors(pred, gt)
    np.testing.assert_allclose(tilt, [0.2])
    np.testing.assert_allclose(pan, [-0.25])  # (-25 - -20) / |-20|
    assert roll.size == 0  # |0.5| deg/s < 1 deg/s


def test_box_stats_tukey_whiskers():
    stats = metrics.box_stats(np.array([1.0, 2, 3, 4, 100]))
    assert (stats["q1"], stats["med"], stats["q3"]) == (2, 3, 4)
    assert (stats["whislo"], stats["whishi"]) == (1, 4)  # 100 lies beyond q3 + 1.5 * IQR = 7
    assert metrics.box_stats(np.array([]), "x") == {"label": "x", "n": 0}


def test_bad_shapes_short_windows_and_nan_are_rejected():
    with pytest.raises(ValueError, match="n, T, 3"):
        metrics.rmse(np.zeros((2, 60, 3)), np.zeros((2, 60, 2)))
    with pytest.raises(ValueError, match="more than 50"):
        metrics.rmse(np.zeros((2, 50, 3)), np.zeros((2, 50, 3)))
    bad = np.zeros((1, 60, 3))
    bad[0, 55, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        metrics.rmse(bad, np.zeros((1, 60, 3)))


def test_sub_windows_are_aligned_with_the_window_start_and_wholly_evaluated():
    assert metrics.sub_windows(100) == [(60, 80), (80, 100)]  # [40, 60) straddles step 50
    assert metrics.sub_windows(100, 20, 60) == [(60, 80), (80, 100)]
    assert metrics.sub_windows(100, 20, 0) == [(0, 20), (20, 40), (40, 60), (60, 80), (80, 100)]
    assert metrics.sub_windows(100, 25) == [(50, 75), (75, 100)]
    assert metrics.sub_windows(90) == [(60, 80)]  # [80, 100) would run past the window
    assert metrics.sub_windows(70) == []


def test_window_metrics_compare_sub_window_means():
    pred = np.zeros((2, 100, 3))
    gt = np.zeros((2, 100, 3))
    pred[:, 50:60] = 1e3  # the settling steps and [40, 60) must not count
    # Window 0, [60, 80): truth 10 deg/s on tilt, prediction alternating 8 and 16 (mean 12).
    gt[0, 60:80, 0] = 10
    pred[0, 60:80:2, 0], pred[0, 61:80:2, 0] = 8, 16
    # [80, 100): truth 20 then 0 deg/s on pan (mean 10), prediction (3, 14, 0): error 5.
    gt[0, 80:90, 1] = 20
    pred[0, 80:100] = [3, 14, 0]
    # Window 1, [60, 80): mean truth 0.5 deg/s (too slow for a relative error), error 4.
    gt[1, 60:80, 2], pred[1, 60:80, 2] = 0.5, 4.5
    # [80, 100): truth -30, prediction -27 deg/s on roll.
    gt[1, 80:100, 2], pred[1, 80:100, 2] = -30, -27
    w = metrics.window_metrics(np.radians(pred), np.radians(gt))
    assert w["window_ms"] == 20 and w["sub_windows_ms"] == [[60, 80], [80, 100]]
    assert (w["n_windows"], w["n_windows_relative"]) == (4, 3)
    assert w["mean_euclidean_error_deg_s"] == pytest.approx((2 + 5 + 4 + 3) / 4)
    assert w["rmse_deg_s"] == pytest.approx(math.sqrt((4 + 25 + 16 + 9) / 4))
    assert w["median_relative_error"] == pytest.approx(0.2)  # of 0.2, 0.5 and 0.1
    # Per millisecond over the same steps, the alternation and the step in the truth count.
    per_ms = (20 * 4 + 10 * math.sqrt(45) + 10 * math.sqrt(205) + 20 * 4 + 20 * 3) / 80
    assert metrics.mean_euclidean_error(np.radians(pred), np.radians(gt), 60) == pytest.approx(
        per_ms
    )
    short = metrics.window_metrics(np.zeros((1, 70, 3)), np.zeros((1, 70, 3)))
    assert short["n_windows"] == 0 and short["rmse_deg_s"] is None


def test_speed_bin_edges_are_half_open():
    speeds = np.array([0, 99.999, 100, 250, 499.9, 500, 1e6])
    np.testing.assert_array_equal(bins.speed_bin_index(speeds), [0, 0, 1, 2, 4, 5, 5])
    np.testing.assert_array_equal(bins.speed_bin_index(np.array([-1, 5, 10]), (0, 10)), [-1, 0, -1])
    assert bins.bin_labels((0, 100, math.inf)) == ["[0, 100)", "[100, inf)"]
    with pytest.raises(ValueError, match="increase"):
        bins.speed_bin_index(np.zeros(1), (0, 10, 10))


def test_per_bin_metrics_counts_medians_and_empty_bins():
    # Speeds 50, 50 (bin 0), 150 (bin 1), 100 (bin 1: the edge belongs to the upper bin).
    pred, gt = windows(
        [[[55, 0, 0], [0, 60, 0]], [[0, 0, 180], [0, 90, 0]]],
        [[[50, 0, 0], [0, 50, 0]], [[0, 0, 150], [0, 100, 0]]],
    )
    per_bin = bins.per_bin_metrics(pred, gt)
    assert [b["n_pairs"] for b in per_bin] == [2, 2, 0, 0, 0, 0]
    assert per_bin[0]["median_relative_error"] == pytest.approx((0.1 + 0.2) / 2)
    assert per_bin[1]["median_relative_error"] == pytest.approx((0.2 + 0.1) / 2)
    assert per_bin[1]["mean_euclidean_error_deg_s"] == pytest.approx((30 + 10) / 2)
    assert per_bin[1]["per_axis"]["roll"]["relative_error"]["n"] == 1
    assert per_bin[1]["per_axis"]["pan"]["relative_error"]["med"] == pytest.approx(-0.1)
    assert per_bin[5]["hi_deg_s"] is None and per_bin[0]["lo_deg_s"] == 0
    assert bins.empty_bins(per_bin) == ["[200, 300)", "[300, 400)", "[400, 500)", "[500, inf)"]


def test_speed_bin_sets_and_user_edges():
    assert bins.parse_speed_bins("paper") == bins.SPEED_BIN_EDGES_DEG_S
    fine = bins.parse_speed_bins("fine")
    assert fine[:5] == (0, 10, 25, 50, 100) and fine[-1] == math.inf
    assert set(bins.SPEED_BIN_EDGES_DEG_S) <= set(fine)  # the paper's bins stay edges
    assert bins.parse_speed_bins("0,20,60") == (0, 20, 60, math.inf)
    assert bins.parse_speed_bins("0,20,inf") == (0, 20, math.inf)
    # Every pair lands in a bin: a fine table counts what the paper's does.
    speeds = np.array([3, 12, 30, 70, 140, 700.0])
    assert (bins.speed_bin_index(speeds, fine) >= 0).all()
    np.testing.assert_array_equal(bins.speed_bin_index(speeds, fine), [0, 1, 2, 3, 4, 8])
    for bad in ("0,50,20", "10,50", "0", "0,a", "slow", ""):
        with pytest.raises(InputError, match="--speed-bins"):
            bins.parse_speed_bins(bad)


def _sequence(path, omega_rows):
    omega = np.asarray(omega_rows, dtype=np.float64)
    ev = EventArray.from_arrays([1], [2], [0], [1], 8, 6)
    gyro = GyroTrace.from_arrays(np.arange(len(omega)) * 1000, omega)
    write_recording(path, Recording(events=ev, gyro=gyro))


def test_training_mean_weights_every_sample(tmp_path):
    (tmp_path / "train").mkdir()
    _sequence(tmp_path / "train" / "seq_000000.h5", [[1, 2, 3], [3, 2, 1]])
    _sequence(tmp_path / "train" / "seq_000001.h5", [[-2, 8, 2]])
    np.testing.assert_allclose(training_mean_omega(tmp_path), [2 / 3, 4, 2])
    pred = mean_predictions(np.array([1.0, 2, 3]), 4, 7)
    assert pred.shape == (4, 7, 3) and (pred[3, 6] == [1, 2, 3]).all()
    with pytest.raises(InputError, match="no sequence files"):
        training_mean_omega(tmp_path, "val")
