"""The demo end to end at a toy size (slow: simulates, trains and evaluates)."""

from __future__ import annotations

import json

import pytest

from spikegyro.demo import DemoConfig, run_demo


@pytest.mark.slow
def test_demo_runs_end_to_end_and_writes_its_summary(tmp_path):
    config = DemoConfig(out=tmp_path / "demo", sequences=12, train_minutes=0.2, workers=1)
    summary = run_demo(config)
    written = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert written["train_steps"] == summary["train_steps"] >= 1
    for key in ("snn", "mean_predictor"):
        assert written[key]["median_relative_error"] > 0
    assert (tmp_path / "demo" / "evaluation" / "report.html").exists()
    assert (tmp_path / "demo" / "run" / "best.pt").exists()
