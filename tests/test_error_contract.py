"""Every command's answer to bad input: exit code 2, one line ``error: ...`` on stderr naming the
problem, no traceback, and nothing written (outputs absent, inputs untouched).

The table runs through the real entry point (``spikegyro.cli.main``) in separate Python
processes: by default two worker processes share the table, each running its cases one after the
other (a fresh interpreter per case costs ~2 s of torch import), and a sample of the cases runs
as ``python -m spikegyro`` each. ``-m slow`` runs every case as its own process.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from contract_inputs import build, spikegyro

from spikegyro.models.registry import PRETRAINED_SNN6

HERE = Path(__file__).resolve().parent
WORKERS = 2

CASES: dict[str, str] = {
    # info: unreadable, malformed and out-of-range inputs
    "info-missing": "info {root}/missing.h5",
    "info-empty-h5": "info {empty.h5}",
    "info-truncated-h5": "info {truncated.h5}",
    "info-garbage-h5": "info {garbage.h5}",
    "info-text-as-h5": "info {text.h5}",
    "info-bad-row": "info {bad_row.txt}",
    "info-ragged-row": "info {ragged.txt}",
    "info-unsorted": "info {unsorted.txt}",
    "info-outside-sensor": "info {outside.txt}",
    "info-npz-no-height": "info {no_height.npz}",
    "info-npz-no-p": "info {no_p.npz}",
    "info-npz-truncated": "info {truncated.npz}",
    "info-npz-empty": "info {empty.npz}",
    "info-npz-gyro-no-omega": "info {gyro_no_omega.npz}",
    "info-npz-bad-attrs": "info {bad_attrs.npz}",
    "info-h5-no-ts": "info {no_ts}",
    "info-h5-bad-xy": "info {bad_xy}",
    "info-unknown-suffix": "info {unknown.xyz}",
    "info-folder": "info {dir}",
    "info-gyro-file": "info {gyro_only.txt}",
    "info-empty-txt": "info {empty.txt}",
    "info-comments-only": "info {comments.txt}",
    "info-zero-width": "info {good.h5} --width 0 --height 10",
    "info-width-alone": "info {good.h5} --width 100",
    # convert
    "convert-missing": "convert {root}/missing.h5 {out}/x.h5",
    "convert-unknown-output": "convert {good.h5} {out}/x.xyz",
    "convert-bad-row": "convert {bad_row.txt} {out}/x.h5",
    "convert-parent-is-file": "convert {good.h5} {existing.csv}/x.h5",
    "convert-bad-rotation": "convert {good.h5} {out}/x.h5 --imu-to-camera bogus",
    "convert-zero-chunk": "convert {good.h5} {out}/x.h5 --chunk-events 0",
    "convert-onto-input": "convert {good.h5} {good.h5}",
    # compare-stats
    "stats-no-sim-files": "compare-stats {good.h5} --sim {dir} --out {out}/s",
    "stats-missing-real": "compare-stats {root}/missing.h5 --sim {data} --out {out}/s",
    "stats-out-is-file": "compare-stats {good.h5} --sim {data} --out {existing.csv}",
    "stats-zero-window": "compare-stats {good.h5} --sim {data} --out {out}/s --window-ms 0",
    "stats-garbage-real": "compare-stats {garbage.h5} --sim {data} --out {out}/s",
    # simulate
    "simulate-negative-contrast-std": "simulate --out {out}/d --sequences 1 --contrast-std -1",
    "simulate-zero-contrast": "simulate --out {out}/d --sequences 1 --contrast-mean 0",
    "simulate-zero-sequences": "simulate --out {out}/d --sequences 0",
    "simulate-bad-compression": "simulate --out {out}/d --sequences 1 --compression zip",
    "simulate-bad-sensor": "simulate --out {out}/d --sequences 1 --sensor bogus",
    "simulate-bad-scene-mix": "simulate --out {out}/d --sequences 1 --sensor davis240c "
    "--scene-mix a,b",
    "simulate-out-is-file": "simulate --out {existing.csv} --sequences 1",
    "simulate-negative-width": "simulate --out {out}/d --sequences 1 --width -10",
    "simulate-zero-focal": "simulate --out {out}/d --sequences 1 --fx 0",
    "simulate-missing-panoramas": "simulate --out {out}/d --sequences 1 --panoramas {root}/nope",
    "simulate-bad-fraction": "simulate --out {out}/d --sequences 1 --procedural-fraction 2",
    # export-official
    "export-missing-src": "export-official {root}/missing {out}/o",
    "export-no-sequences": "export-official {dir} {out}/o",
    "export-out-is-file": "export-official {data} {existing.csv}",
    # show
    "show-unknown-figure-format": "show {good.h5} --out {out}/fig.xyz",
    "show-negative-window": "show {good.h5} --out {out}/fig.png --window-ms -5",
    "show-zero-max-events": "show {good.h5} --out {out}/fig.png --max-events 0",
    "show-garbage": "show {garbage.h5} --out {out}/fig.png",
    "show-out-is-folder": "show {good.h5} --out {existing_dir}",
    # evaluate
    "evaluate-zero-batch": "evaluate --data {data} --out {out}/e --batch-size 0",
    "evaluate-unknown-device": "evaluate --data {data} --out {out}/e --device foo",
    "evaluate-checkpoint-folder": "evaluate --data {data} --out {out}/e --checkpoint {dir}",
    "evaluate-garbage-checkpoint": "evaluate --data {data} --out {out}/e --checkpoint {garbage.pt}",
    "evaluate-bad-split": "evaluate --data {data} --out {out}/e --split bogus",
    "evaluate-missing-data": "evaluate --data {root}/missing --out {out}/e",
    "evaluate-out-is-file": "evaluate --data {data} --out {existing.csv}",
    "evaluate-zero-limit": "evaluate --data {data} --out {out}/e --limit 0",
    "evaluate-bad-model": "evaluate --data {data} --out {out}/e --model bogus",
    "evaluate-unknown-bundled-name": "evaluate --data {data} --out {out}/e --checkpoint snn7",
    "evaluate-decreasing-bins": "evaluate --data {data} --out {out}/e --speed-bins 0,50,20",
    # evaluate-real
    "real-out-is-file": "evaluate-real {good.h5} --out {existing.csv}",
    "real-zero-intrinsics": "evaluate-real {good.h5} --out {out}/r --intrinsics 0 0 120 90",
    "real-bad-offset": "evaluate-real {good.h5} --out {out}/r --gyro-offset soon",
    "real-bins-not-from-zero": "evaluate-real {good.h5} --out {out}/r --speed-bins 10,50",
    "real-checkpoint-folder": "evaluate-real {good.h5} --out {out}/r --checkpoint {dir}",
    "real-negative-warmup": "evaluate-real {good.h5} --out {out}/r --warmup-ms -1",
    "real-bad-gyro": "evaluate-real {good.h5} --out {out}/r --gyro {bad_gyro.txt}",
    "real-bad-row": "evaluate-real {bad_row.txt} --out {out}/r",
    "real-zero-focal-calib": "evaluate-real {good.h5} --out {out}/r --calib {zero_calib.txt}",
    "real-short-calib": "evaluate-real {good.h5} --out {out}/r --calib {bad_calib.txt}",
    # report
    "report-not-a-run": "report {dir} --out {out}/rep",
    "report-missing-run": "report {root}/missing --out {out}/rep",
    # export-nir
    "nir-out-is-folder": "export-nir {pretrained} {existing_dir}",
    "nir-garbage-checkpoint": "export-nir {garbage.pt} {out}/x.nir",
    "nir-checkpoint-folder": "export-nir {dir} {out}/x.nir",
    # train
    "train-unknown-device": "train --data {data} --out {out}/t --device foo",
    "train-bogus-model-kwargs": "train --data {data} --out {out}/t --model-kwargs {bogus_kwargs}",
    "train-model-kwargs-list": "train --data {data} --out {out}/t --model-kwargs [1]",
    "train-zero-batch": "train --data {data} --out {out}/t --batch-size 0",
    "train-negative-lr": "train --data {data} --out {out}/t --lr -1",
    "train-garbage-init": "train --data {data} --out {out}/t --init {garbage.pt}",
    "train-unknown-bundled-init": "train --data {data} --out {out}/t --init snn7",
    "train-missing-data": "train --data {root}/missing --out {out}/t",
    "train-out-is-file": "train --data {data} --out {existing.csv}",
    "train-bad-model": "train --data {data} --out {out}/t --model bogus",
    "train-real-no-calibration": "train --data {data} --out {out}/t --real {events.txt}",
    "train-real-unreadable": "train --data {data} --out {out}/t --real {garbage.h5} "
    "--real-calib 200,200,120,90",
    "train-real-bad-calib": "train --data {data} --out {out}/t --real {events.txt} "
    "--real-calib 200,200",
    "train-real-ann": "train --data {data} --out {out}/t --model ann6 --real {events.txt} "
    "--real-calib 200,200,120,90",
    "train-real-bad-share": "train --data {data} --out {out}/t --real {events.txt} "
    "--real-calib 200,200,120,90 --real-share 0",
    "train-real-bad-loss": "train --data {data} --out {out}/t --real {events.txt} "
    "--real-calib 200,200,120,90 --real-loss bogus",
    "adapt-no-calibration": "adapt {events.txt} --out {out}/a.pt",
    "adapt-calib-and-intrinsics": "adapt {events.txt} --out {out}/a.pt --calib {events.txt} "
    "--intrinsics 200 200 120 90",
    "adapt-ann-checkpoint": "adapt {events.txt} --out {out}/a.pt --intrinsics 200 200 120 90 "
    "--checkpoint ann6",
    "adapt-out-missing-folder": "adapt {events.txt} --out {out}/no/a.pt "
    "--intrinsics 200 200 120 90",
    "adapt-too-short": "adapt {events.txt} --out {out}/a.pt --intrinsics 200 200 120 90 --end 0.05",
    "adapt-zero-budget": "adapt {events.txt} --out {out}/a.pt --intrinsics 200 200 120 90 "
    "--max-minutes 0",
    # relay-log
    "relay-not-a-run": "relay-log {dir} --relay {out}/relay",
    "relay-missing-run": "relay-log {root}/missing --relay {out}/relay",
    # predict
    "predict-not-hdf5": "predict {garbage.h5} --out {out}/p.csv",
    "predict-text-as-h5": "predict {text.h5} --out {out}/p.csv",
    "predict-unknown-output": "predict {good.h5} --out {out}/p.xyz",
    "predict-checkpoint-folder": "predict {good.h5} --checkpoint {dir} --out {out}/p.csv",
    "predict-garbage-checkpoint": "predict {good.h5} --checkpoint {garbage.pt} --out {out}/p.csv",
    "predict-unknown-bundled-name": "predict {good.h5} --checkpoint snn7 --out {out}/p.csv",
    "predict-zero-intrinsics": "predict {good.h5} --intrinsics 0 0 120 90 --out {out}/p.csv",
    "predict-out-is-folder": "predict {good.h5} --out {existing_dir}",
    "predict-bad-row": "predict {bad_row.txt} --out {out}/p.csv",
    "predict-unknown-device": "predict {good.h5} --device foo --out {out}/p.csv",
    "predict-bad-gyro": "predict {good.h5} --gyro {bad_gyro.txt} --out {out}/p.csv",
    "predict-end-before-start": "predict {good.h5} --start 0.2 --end 0.1 --out {out}/p.csv",
    "predict-short-calib": "predict {good.h5} --calib {bad_calib.txt} --out {out}/p.csv",
    "predict-npz-no-height": "predict {no_height.npz} --out {out}/p.csv",
    # baseline cmax
    "cmax-not-hdf5": "baseline cmax {garbage.h5} --out {out}/c.csv",
    "cmax-unknown-output": "baseline cmax {good.h5} --out {out}/c.xyz",
    "cmax-zero-intrinsics": "baseline cmax {good.h5} --intrinsics 0 0 120 90 --out {out}/c.csv",
    "cmax-bad-row": "baseline cmax {bad_row.txt} --out {out}/c.csv",
    "cmax-out-is-folder": "baseline cmax {good.h5} --out {existing_dir}",
    "cmax-end-before-start": "baseline cmax {good.h5} --start 0.2 --end 0.1 --out {out}/c.csv",
    "cmax-parent-is-file": "baseline cmax {good.h5} --out {existing.csv}/c.csv",
    # calibrate-imu
    "calibrate-imu-not-hdf5": "calibrate-imu {garbage.h5}",
    "calibrate-imu-bad-gyro": "calibrate-imu {good.h5} --gyro {bad_gyro.txt}",
    "calibrate-imu-end-before-start": "calibrate-imu {good.h5} --start 0.2 --end 0.1",
    # demo
    "demo-out-is-file": "demo --out {existing.csv}",
    "demo-zero-sequences": "demo --out {out}/demo --test-sequences 0",
}

SAMPLE = ("info-bad-row", "simulate-negative-contrast-std", "predict-not-hdf5",
          "train-unknown-device", "evaluate-zero-batch", "nir-out-is-folder")  # fmt: skip
"""Cases also run as ``python -m spikegyro`` by default, one process each."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("contract")
    paths = {name: str(path) for name, path in build(root / "in").items()}
    return {**paths, "root": str(root / "in"), "pretrained": str(PRETRAINED_SNN6),
            "bogus_kwargs": '{"bogus": 1}'}  # fmt: skip


def _argv(case_id: str, inputs: dict[str, str], work: Path) -> tuple[list[str], Path]:
    """The case's arguments, with its own empty working folder as ``{out}`` and cwd."""
    out = work / case_id
    out.mkdir(parents=True, exist_ok=True)
    names = {**inputs, "out": str(out)}
    fill = [
        re.sub(r"\{([^{}]+)\}", lambda m: names[m.group(1)], part)
        for part in CASES[case_id].split()
    ]
    return fill, out


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))}


def _check(case_id: str, result: dict, out: Path) -> list[str]:
    """The contract's three properties; returns what is broken (empty: kept)."""
    problems = []
    err = result["stderr"].strip()
    if result["returncode"] != 2:
        problems.append(f"exit {result['returncode']}")
    if "Traceback" in err:
        problems.append("traceback")
    lines = err.splitlines()
    if len(lines) != 1 or not lines[0].startswith("error: "):
        problems.append(f"{len(lines)} stderr lines")
    if leftovers := sorted(str(p.relative_to(out)) for p in out.rglob("*")):
        problems.append(f"left {leftovers[:3]}")
    return [f"{case_id}: {', '.join(problems)}\n    {err[-600:]}"] if problems else []


def _run_workers(case_ids: list[str], inputs: dict[str, str], tmp: Path) -> dict[str, dict]:
    """The cases through ``cli.main`` in WORKERS processes, each taking its share in turn."""
    todo = [(cid, *_argv(cid, inputs, tmp)) for cid in case_ids]
    shares = [
        [(cid, argv, str(cwd)) for cid, argv, cwd in todo[k::WORKERS]] for k in range(WORKERS)
    ]

    def work(k: int) -> dict[str, dict]:
        cases, results = tmp / f"cases{k}.json", tmp / f"results{k}.json"
        cases.write_text(json.dumps(shares[k]))
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        done = subprocess.run(
            [sys.executable, str(HERE / "contract_inputs.py"), str(cases), str(results)],
            capture_output=True, text=True, timeout=600, env=env,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        return json.loads(results.read_text())

    with ThreadPoolExecutor(WORKERS) as pool:
        return {k: v for part in pool.map(work, range(WORKERS)) for k, v in part.items()}


def _run_processes(case_ids: list[str], inputs: dict[str, str], tmp: Path) -> dict[str, dict]:
    def one(case_id: str) -> dict:
        argv, out = _argv(case_id, inputs, tmp)
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        done = subprocess.run(
            spikegyro(*argv), cwd=out, capture_output=True, text=True, timeout=600, env=env
        )
        return {"returncode": done.returncode, "stdout": done.stdout, "stderr": done.stderr}

    with ThreadPoolExecutor(WORKERS) as pool:
        return dict(zip(case_ids, pool.map(one, case_ids), strict=True))


def _assert_contract(results: dict[str, dict], work: Path) -> None:
    broken = [p for cid, r in sorted(results.items()) for p in _check(cid, r, work / cid)]
    assert not broken, f"{len(broken)} of {len(results)} cases break the contract:\n" + "\n".join(
        broken
    )


def test_the_table_is_large_and_covers_every_command() -> None:
    from spikegyro.cli import _COMMANDS

    assert len(CASES) >= 60
    covered = {text.split()[0] for text in CASES.values()}
    assert covered == set(_COMMANDS)


def test_every_bad_input_is_one_line_exit_2_and_writes_nothing(inputs, tmp_path) -> None:
    before = _snapshot(Path(inputs["root"]))
    _assert_contract(_run_workers(list(CASES), inputs, tmp_path), tmp_path)
    assert _snapshot(Path(inputs["root"])) == before, "an input file or folder was changed"


def test_a_sample_of_bad_inputs_as_separate_processes(inputs, tmp_path) -> None:
    _assert_contract(_run_processes(list(SAMPLE), inputs, tmp_path), tmp_path)


@pytest.mark.slow
def test_every_bad_input_as_a_separate_process(inputs, tmp_path) -> None:
    before = _snapshot(Path(inputs["root"]))
    _assert_contract(_run_processes(list(CASES), inputs, tmp_path), tmp_path)
    assert _snapshot(Path(inputs["root"])) == before
