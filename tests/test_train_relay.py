"""The relay log: segments appended on the relay's clock, nothing appended twice."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from spikegyro.errors import InputError
from spikegyro.train.relay import RELAY_FIELDS, append_segment, plot_relay, read_state

RUN_FIELDS = [f for f in RELAY_FIELDS if f != "segment"]


def _write_run_log(run: Path, steps: list[int], elapsed: list[float]) -> None:
    run.mkdir(parents=True, exist_ok=True)
    with (run / "log.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, RUN_FIELDS)
        w.writeheader()
        for s, e in zip(steps, elapsed, strict=True):
            w.writerow(
                {
                    "step": s,
                    "loss": 1.0 / s,
                    "lr": 1e-4,
                    "elapsed_s": e,
                    "val_median_rel": 0.5 if s % 200 == 0 else "",
                }
            )


def test_segments_are_shifted_onto_the_relay_clock(tmp_path: Path) -> None:
    relay, run = tmp_path / "relay", tmp_path / "run"
    relay.mkdir()
    (relay / "relay.json").write_text(
        json.dumps(
            {"step_offset": 1000, "elapsed_offset_s": 50.0, "last_run_step": 0, "segments": []}
        )
    )
    _write_run_log(run, [100, 200], [10.0, 20.0])
    first = append_segment(run, relay, "a")
    assert first == {
        "segment": 1,
        "first_step": 1100,
        "last_step": 1200,
        "train_s": 70.0,
        "note": "a",
    }
    # The run is resumed: its log keeps the old rows and gains new ones.
    _write_run_log(run, [100, 200, 300, 400], [10.0, 20.0, 30.0, 45.0])
    second = append_segment(run, relay)
    assert (second["segment"], second["first_step"], second["last_step"]) == (2, 1300, 1400)
    assert second["train_s"] == pytest.approx(25.0)
    with (relay / "relay_log.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(r["step"]) for r in rows] == [1100, 1200, 1300, 1400]
    assert [r["segment"] for r in rows] == ["1", "1", "2", "2"]
    assert read_state(relay).last_run_step == 400
    with pytest.raises(InputError, match="no rows after run step 400"):
        append_segment(run, relay)
    png = plot_relay(relay / "relay_log.csv", relay / "curve.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_shipped_relay_state_matches_its_log() -> None:
    relay = Path(__file__).resolve().parents[1] / "runs" / "snn6"
    state = read_state(relay)
    with (relay / "relay_log.csv").open() as f:
        last = list(csv.DictReader(f))[-1]
    with (relay / "log.csv").open() as f:
        run_last = list(csv.DictReader(f))[-1]
    assert int(last["step"]) == int(run_last["step"]) + state.step_offset
    assert int(run_last["step"]) == state.last_run_step
    assert state.segments[-1]["last_step"] == int(last["step"])


def test_segments_recorded_as_gpu_seconds_are_read_as_training_seconds(tmp_path: Path) -> None:
    """relay.json files from before CPU runs were relayed keep working, and the next segment
    rewrites them with one name."""
    relay, run = tmp_path / "relay", tmp_path / "run"
    relay.mkdir()
    old = {"segment": 1, "first_step": 10, "last_step": 100, "gpu_s": 90.0, "note": "gpu"}
    (relay / "relay.json").write_text(
        json.dumps(
            {"step_offset": 0, "elapsed_offset_s": 0.0, "last_run_step": 100, "segments": [old]}
        )
    )
    assert read_state(relay).segments[0]["train_s"] == 90.0
    _write_run_log(run, [100, 200], [90.0, 120.0])
    append_segment(run, relay, "cpu")
    written = json.loads((relay / "relay.json").read_text())["segments"]
    assert [list(entry) for entry in written] == [
        ["segment", "first_step", "last_step", "train_s", "note"]
    ] * 2
    assert written[0]["train_s"] == 90.0
