"""Which row of the paper's Table I a model's results are shown beside."""

from __future__ import annotations

import pytest

from spikegyro.evaluate.report import PAPER_RESULTS, overall_table, paper_row, paper_row_from_name


def _entry(arch, representation, name="anything", **extra):
    return {"name": name, "checkpoint_model": arch, "input": {"representation": representation},
            **extra}  # fmt: skip


@pytest.mark.parametrize(
    ("arch", "representation", "row", "numbers"),
    [
        ("snn6", "spikes", "SNN-6", (0.26, 66.3)),
        ("ann6", "voxel", "ANN-6 (voxel)", (0.22, 59.0)),
        ("resnet50", "frames", "ResNet-50 (accumulated frames)", (0.22, 66.8)),
        ("resnet50", "voxel", "ResNet-50 (voxel)", (0.15, 36.8)),
        ("ann6", "frames", None, None),  # not in the paper
        ("snn6", "voxel", None, None),
    ],
)
def test_checkpoint_architecture_and_input_decide_the_row(arch, representation, row, numbers):
    # The display name is free text and must not matter when the checkpoint says what it is.
    assert paper_row(_entry(arch, representation, name="SNN-6")) == row
    if numbers:
        paper = PAPER_RESULTS[row]
        assert (paper["median_relative_error"], paper["mean_euclidean_error_deg_s"]) == numbers


def test_mean_and_other_methods():
    assert paper_row({"name": "Mean", "method": "mean"}) == "Mean"
    assert PAPER_RESULTS["Mean"]["mean_euclidean_error_deg_s"] == 226.9
    assert paper_row({"name": "Mean", "method": "cmax"}) is None  # CMax run named "Mean"
    assert paper_row({"name": "ResNet-50 (V)"}) == "ResNet-50 (voxel)"  # old file: by name


@pytest.mark.parametrize(
    ("name", "row"),
    [
        ("SNN-6", "SNN-6"),
        ("SNN-6 (official)", "SNN-6"),
        ("SNN-6 (E) [run2]", "SNN-6"),
        ("ANN-6", "ANN-6 (voxel)"),
        ("ANN-6 (V)", "ANN-6 (voxel)"),
        ("ann6 (voxel grid)", "ANN-6 (voxel)"),
        ("ResNet-50 (A)", "ResNet-50 (accumulated frames)"),
        ("ResNet50 (accumulated frames)", "ResNet-50 (accumulated frames)"),
        ("ResNet-50 (V)", "ResNet-50 (voxel)"),
        ("resnet-50 (voxel) [b]", "ResNet-50 (voxel)"),
        ("Mean", "Mean"),
        ("ResNet-50", None),  # which input? ambiguous
        ("ANN-6 (A)", None),
        ("ANN-6 (V) (A)", None),
        ("SNN-6 (something)", None),
        ("CMax", None),
        ("Mean (V)", None),
    ],
)
def test_display_names_map_to_rows(name, row):
    assert paper_row_from_name(name) == row


def test_overall_table_shows_both_metric_groups_and_the_matched_paper_row():
    metrics = {"median_relative_error": 0.5, "mean_euclidean_error_deg_s": 40.0,
               "rmse_deg_s": 50.0, "n_pairs": 100}  # fmt: skip
    window = {"window_ms": 20, "sub_windows_ms": [[60, 80], [80, 100]],
              "median_relative_error": 0.25, "mean_euclidean_error_deg_s": 20.0,
              "rmse_deg_s": 30.0, "n_windows": 4, "n_windows_relative": 4}  # fmt: skip
    models = {
        "my net": _entry("resnet50", "voxel", metrics=metrics, window_metrics=window),
        "old run": {"name": "old run", "metrics": metrics},  # written before window metrics
    }
    table = overall_table(models, "Overall")
    assert "per ms (steps ≥ 50)" in table.header[1]
    assert "per 20 ms window (mean prediction vs mean truth)" in table.header[5]
    assert "[60, 80) ms and [80, 100) ms" in table.caption
    cells = dict(zip(table.header, table.rows[0], strict=True))
    assert table.rows[0][1:9] == ["0.500", "40.0", "50.0", "100", "0.250", "20.0", "30.0", "4"]
    assert cells["paper row (Table I)"] == "ResNet-50 (voxel)"
    assert (cells["paper: median rel. error"], cells['paper: "RMSE" [deg/s]']) == ("0.15", "36.8")
    assert table.rows[1][5:12] == ["-"] * 7
