"""bench/gpu_step.py executes on a CPU in its tiny configuration (its numbers matter on a GPU).

What it can check here: the fused variant (Triton's interpreter, when Triton is installed) gives
the reference's output exactly, and with ``--data`` both data paths train and report the run's
rate beside the bare step's.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording

BENCH = Path(__file__).resolve().parents[1] / "bench" / "gpu_step.py"


def run_bench(tmp_path: Path, *extra: str) -> dict:
    out = tmp_path / "result.json"
    command = [sys.executable, str(BENCH), "--device", "cpu", "--tiny", "--json", str(out)]
    done = subprocess.run(command + list(extra), capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "| variant | ms/step |" in done.stdout
    return json.loads(out.read_text())


def _tiny_reference_output() -> torch.Tensor:
    """SNN-6's output on the bench's tiny input, computed here the way the bench sets it up."""
    from spikegyro.models.snn6 import SNN6

    torch.manual_seed(0)
    model = SNN6()
    x = (torch.rand(1, 2, 64, 64, 12) < 0.1).float()
    with torch.no_grad():
        return model(x)


def test_tiny_bench_runs_and_the_fused_step_matches_the_reference(tmp_path):
    result = run_bench(tmp_path)
    rows = {r["variant"]: r for r in result["steps"]}
    reference = rows["reference"]
    assert reference["ms_per_step"] > 0 and reference["out_rel_diff"] is None
    expected = float(_tiny_reference_output().abs().max())
    assert expected > 0 and reference["out_abs_max"] == pytest.approx(expected, rel=1e-5)
    if importlib.util.find_spec("triton") is not None:
        assert rows["fused"]["out_rel_diff"] == 0.0  # bit-identical spikes, same output
    else:
        assert "fused" not in rows


@pytest.mark.slow
def test_tiny_bench_compares_both_data_paths(tmp_path):
    rng = np.random.default_rng(0)
    for i, split in enumerate(("train", "train", "val")):
        n, ms = 5000, 40
        t = np.sort(rng.integers(0, ms * 1000, n))
        events = EventArray.from_arrays(
            rng.integers(0, 64, n), rng.integers(0, 64, n), t, rng.integers(0, 2, n), 64, 64
        )
        gyro_t = np.arange(0, ms * 1000 + 1, 1000)
        gyro = GyroTrace.from_arrays(gyro_t, rng.standard_normal((gyro_t.size, 3)))
        write_recording(tmp_path / "data" / split / f"seq_{i:06d}.h5", Recording(events, gyro))
    result = run_bench(tmp_path, "--data", str(tmp_path / "data"))
    paths = {r["data_path"]: r for r in result["data_paths"]}
    assert set(paths) == {"dense", "events"}
    for r in paths.values():
        assert r["steps"] == 3 and r["run_samples_per_s"] > 0 and r["bare_samples_per_s"] > 0
