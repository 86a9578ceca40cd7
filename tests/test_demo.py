"""The demo end to end at a toy size (slow: simulates, evaluates, streams and fine-tunes), and
its comparison report's per-axis table (fast)."""

from __future__ import annotations

import json

import pytest

from spikegyro.demo import DemoConfig, run_demo
from spikegyro.evaluate.compare import compare_runs
from spikegyro.models.registry import PRETRAINED_SNN6


@pytest.mark.slow
def test_demo_runs_end_to_end_and_writes_its_summary(tmp_path):
    config = DemoConfig(
        out=tmp_path / "demo",
        test_sequences=2,
        train_sequences=3,
        recording_s=0.3,
        finetune_minutes=0.1,
        workers=1,
    )
    summary = run_demo(config)
    written = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert written["test_windows"] == summary["test_windows"] == 10
    for key in ("snn", "cmax", "mean_predictor"):
        assert written[key]["median_relative_error"] > 0
    assert written["stream"]["seconds"] == pytest.approx(0.3)
    assert written["finetune"]["steps"] >= 1
    assert set(written["timings_s"]) == {"simulate_s", "evaluate_s", "stream_s", "finetune_s",
                                         "total"}  # fmt: skip
    for path in ("report/report.html", "evaluation-snn6/report.html", "recording-pred.png"):
        assert (tmp_path / "demo" / path).exists(), path


def _run_dir(root, name, method, scale):
    """An ``evaluate`` output folder from the shipped weights' metrics, renamed and rescaled."""
    data = json.loads((PRETRAINED_SNN6.parent / "snn6" / "test_metrics.json").read_text())
    data["model"].update(name=name, method=method)
    if method != "checkpoint":  # CMax: raw events, no spikes, no checkpoint
        for key in ("spikes", "input", "source", "checkpoint_model"):
            data["model"].pop(key, None)
    for stats in data["model"]["metrics"]["per_axis"].values():
        stats["mean_abs_error_deg_s"] *= scale
    run = root / name
    run.mkdir()
    (run / "metrics.json").write_text(json.dumps(data))
    return run, data


def test_the_comparison_report_puts_every_estimators_per_axis_error_side_by_side(tmp_path):
    """The demo's report/ (compare_runs) has one row per estimator with tilt, pan and roll."""
    snn_dir, snn = _run_dir(tmp_path, "snn", "checkpoint", 1.0)
    cmax_dir, cmax = _run_dir(tmp_path, "cmax", "cmax", 0.25)
    compare_runs([snn_dir, cmax_dir], tmp_path / "report")
    md = (tmp_path / "report" / "report.md").read_text()
    html = (tmp_path / "report" / "report.html").read_text()
    assert "Per-axis mean absolute error" in md and "Per-axis mean absolute error" in html
    header = "| model | tilt [deg/s] | pan [deg/s] | roll [deg/s] | mean Eucl. error [deg/s] |"
    assert header in md
    section = md[md.index(header) :].split("\n\n")[0]
    for data in (snn, cmax):
        m = data["model"]
        axes = m["metrics"]["per_axis"]
        cells = [f"{axes[a]['mean_abs_error_deg_s']:.1f}" for a in ("tilt", "pan", "roll")]
        row = f"| {m['name']} | " + " | ".join(cells)
        assert row in section, row
    mean_axes = snn["mean"]["metrics"]["per_axis"]
    assert f"| Mean | {mean_axes['tilt']['mean_abs_error_deg_s']:.1f} |" in section
