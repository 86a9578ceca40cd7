"""Per-scene-kind metrics against plain numpy, window kinds from sequence files, the table."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.evaluate.kinds import kind_table, per_kind_metrics, window_scene_kinds
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording
from spikegyro.train.data import sequence_windows


def _arrays() -> tuple[np.ndarray, np.ndarray, list[str]]:
    rng = np.random.default_rng(3)
    gt = np.radians(rng.normal(0, 150, (5, 53, 3)))
    gt[2, 51] = np.radians([0.3, -0.2, 0.5])  # under 1 deg/s: left out of the relative error
    pred = gt + np.radians(rng.normal(0, 40, gt.shape))
    return pred, gt, ["sparse", "photo", "sparse", "unknown", "office"]


def test_per_kind_metrics_match_numpy_on_each_kind():
    pred, gt, kinds = _arrays()
    result = per_kind_metrics(pred, gt, kinds)
    assert list(result) == ["sparse", "office", "photo", "unknown"]
    for kind, windows in {"sparse": [0, 2], "photo": [1], "unknown": [3], "office": [4]}.items():
        err = np.degrees(pred[windows, 50:] - gt[windows, 50:]).reshape(-1, 3)
        speed = np.degrees(np.linalg.norm(gt[windows, 50:], axis=-1)).ravel()
        norm = np.linalg.norm(err, axis=-1)
        m = result[kind]
        assert m["n_windows"] == len(windows) and m["n_pairs"] == 3 * len(windows)
        keep = speed >= 1.0
        assert keep.sum() == m["n_pairs"] - (kind == "sparse")  # the slow step is in "sparse"
        assert m["median_relative_error"] == pytest.approx(np.median(norm[keep] / speed[keep]))
        assert m["mean_euclidean_error_deg_s"] == pytest.approx(norm.mean())
        assert m["rmse_deg_s"] == pytest.approx(np.sqrt(np.mean(norm**2)))
        mae = np.abs(err).mean(axis=0)
        assert [m["mean_abs_error_deg_s"][a] for a in ("tilt", "pan", "roll")] == pytest.approx(mae)
    with pytest.raises(ValueError, match="one kind per window"):
        per_kind_metrics(pred, gt, kinds[:-1])


def test_kind_table_rows_and_no_table_without_known_kinds():
    pred, gt, kinds = _arrays()
    entries = [
        {"name": "SNN-6", "per_scene_kind": per_kind_metrics(pred, gt, kinds)},
        {"name": "Mean", "per_scene_kind": per_kind_metrics(np.zeros_like(gt), gt, kinds)},
    ]
    table = kind_table(entries)
    assert [row[:3] for row in table.rows[:2]] == [
        ["sparse", "SNN-6", "2"],
        ["sparse", "Mean", "2"],
    ]
    assert len(table.rows) == 8 and len(table.header) == 8
    roll = entries[0]["per_scene_kind"]["photo"]["mean_abs_error_deg_s"]["roll"]
    assert table.rows[4][7] == f"{roll:.1f}"
    unknown = [{"name": "SNN-6", "per_scene_kind": per_kind_metrics(pred, gt, ["unknown"] * 5)}]
    assert kind_table(unknown) is None


def test_windows_take_the_kind_of_their_sequence_file(tmp_path):
    events = EventArray.from_arrays([1, 2], [1, 2], [10, 150_000], [0, 1], 8, 8)
    gyro = GyroTrace.from_arrays(np.arange(0, 200_001, 1000), np.zeros((201, 3)))
    windows = []
    for name, attrs in {
        "a": {"scene_kind": "office"},
        "b": {"scene": "sparse/test/1", "generator": "spikegyro 0.1.0"},  # before scene_kind
        "c": {},  # not simulated here
    }.items():
        path = write_recording(tmp_path / f"{name}.h5", Recording(events, gyro, attrs))
        windows += sequence_windows(Recording(events, gyro, attrs), 100, str(path))
    assert window_scene_kinds(windows) == ["office"] * 2 + ["sparse"] * 2 + ["unknown"] * 2
