"""The demo end to end at a toy size (slow: simulates, evaluates, streams and fine-tunes)."""

from __future__ import annotations

import json

import pytest

from spikegyro.demo import DemoConfig, run_demo


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
