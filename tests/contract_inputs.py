"""Tiny good and bad inputs for the command line's error-contract tests, made in a tmp folder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording

SENSOR = (240, 180)


def recording(duration_ms: int, rate_per_ms: int, seed: int = 0) -> Recording:
    """Random events and a slow sinusoidal gyro on a 240x180 sensor."""
    rng = np.random.default_rng(seed)
    n = duration_ms * rate_per_ms
    t = np.sort(rng.integers(0, duration_ms * 1000, n))
    events = EventArray.from_arrays(
        rng.integers(0, SENSOR[0], n), rng.integers(0, SENSOR[1], n), t,
        rng.integers(0, 2, n), *SENSOR,
    )  # fmt: skip
    gyro_t = np.arange(0, duration_ms * 1000 + 1, 1000)
    phase = gyro_t[:, None] / 1e5 + np.arange(3)
    return Recording(events, GyroTrace.from_arrays(gyro_t, np.sin(phase)))


def build(root: Path) -> dict[str, Path]:
    """Every input the tests name, under ``root``; returns name -> path."""
    root.mkdir(parents=True, exist_ok=True)
    p: dict[str, Path] = {}

    def put(name: str, data: bytes | str) -> None:
        p[name] = root / name
        if isinstance(data, str):
            p[name].write_text(data)
        else:
            p[name].write_bytes(data)

    rec = recording(300, 20)
    p["good.h5"] = write_recording(root / "good.h5", rec)
    p["good.npz"] = write_recording(root / "good.npz", rec)
    p["events.txt"] = write_recording(root / "events.txt", rec)
    good = p["good.h5"].read_bytes()
    put("truncated.h5", good[: len(good) // 3])
    put("garbage.h5", bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8)))
    put("text.h5", "t x y p\n0.1 1 2 1\n")
    put("empty.h5", b"")
    put("empty.npz", b"")
    put("empty.txt", "")
    put("comments.txt", "# only a comment\n")
    lines = p["events.txt"].read_text().splitlines()
    put("bad_row.txt", "\n".join([*lines[:50], "0.0101 12 oops 1", *lines[50:]]) + "\n")
    put("ragged.txt", "\n".join([*lines[:50], "0.0101 12 13", *lines[50:]]) + "\n")
    put("unsorted.txt", "\n".join([lines[60], *lines[:50]]) + "\n")
    put("outside.txt", "0.001 500 20 1\n0.002 3 4 0\n")
    put("gyro_only.txt", "0.0 0.1 0.2 0.3\n0.001 0.1 0.2 0.3\n")
    put("unknown.xyz", "hello\n")
    put("bad_calib.txt", "200 200 120\n")
    put("zero_calib.txt", "0 200 120 90 0 0 0 0 0\n")
    put("bad_gyro.txt", "0.0 0.1 0.2\n0.001 0.1\n")
    p["truncated.npz"] = root / "truncated.npz"
    p["truncated.npz"].write_bytes(p["good.npz"].read_bytes()[:200])
    ev = rec.events
    np.savez(root / "no_height.npz", x=ev.x, y=ev.y, t=ev.t, p=ev.p, width=240)
    np.savez(root / "no_p.npz", x=ev.x, y=ev.y, t=ev.t)
    np.savez(root / "gyro_no_omega.npz", x=ev.x, y=ev.y, t=ev.t, p=ev.p, gyro_t=ev.t[:5])
    np.savez(root / "bad_attrs.npz", x=ev.x, y=ev.y, t=ev.t, p=ev.p, attrs="{not json")
    for name in ("no_height.npz", "no_p.npz", "gyro_no_omega.npz", "bad_attrs.npz"):
        p[name] = root / name
    with h5py.File(root / "no_ts.h5", "w") as f:
        f["ev_xy"] = np.stack([ev.x, ev.y], axis=1)
        f["ev_pol"] = ev.p
    with h5py.File(root / "bad_xy.h5", "w") as f:
        f["ev_xy"], f["ev_ts"], f["ev_pol"] = ev.x, ev.t, ev.p
    with h5py.File(root / "empty_events.h5", "w") as f:
        f["ev_xy"], f["ev_ts"], f["ev_pol"] = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    p.update(no_ts=root / "no_ts.h5", bad_xy=root / "bad_xy.h5")
    p["empty_events.h5"] = root / "empty_events.h5"
    p["dir"] = root / "a_folder"
    p["dir"].mkdir()
    put("garbage.pt", b"not a torch checkpoint at all")
    put("existing.csv", "t,wx,wy,wz\n")
    p["existing_dir"] = root / "existing_dir"
    p["existing_dir"].mkdir()
    (p["existing_dir"] / "keep.txt").write_text("keep\n")
    p["data"] = root / "data"
    for split, seed in (("train", 2), ("test", 3)):
        write_recording(p["data"] / split / "seq_000000.h5", recording(200, 5, seed))
    return p


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of a running process (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def interrupt_after(
    command: list[str], ready: Callable[[int], bool], *, cwd: Path, timeout_s: float = 300
) -> subprocess.CompletedProcess[str]:
    """Run ``command``; send SIGINT once ``ready(pid)`` holds; wait for it to end."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        command,
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # A test run started in the background (nohup, `cmd &` in a script) ignores SIGINT, and
        # an ignored signal stays ignored across exec: give the command a terminal's default.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and not ready(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=timeout_s)
    return subprocess.CompletedProcess(command, proc.returncode, stdout, stderr)


def spikegyro(*args: str) -> list[str]:
    return [sys.executable, "-m", "spikegyro", *args]


def run_in_process(cases: list[tuple[str, list[str], str]]) -> dict[str, dict]:
    """Run each (id, argv, cwd) through ``spikegyro.cli.main`` in this process, one after the
    other, with file descriptors 1 and 2 captured; what a separate process would report."""
    import tempfile
    import traceback

    from spikegyro import cli

    results = {}
    for case_id, argv, cwd in cases:
        with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
            sys.stdout.flush(), sys.stderr.flush()
            saved = os.dup(1), os.dup(2)
            os.dup2(out.fileno(), 1), os.dup2(err.fileno(), 2)
            here = os.getcwd()
            code: int | str | None = 0
            try:
                os.chdir(cwd)
                sys.argv = ["spikegyro", *argv]
                cli.main()
            except SystemExit as exc:
                code = exc.code
            except BaseException:  # what the interpreter would print for an uncaught error
                traceback.print_exc()
                code = 1
            finally:
                os.chdir(here)
                sys.stdout.flush(), sys.stderr.flush()
                os.dup2(saved[0], 1), os.dup2(saved[1], 2)
                os.close(saved[0]), os.close(saved[1])
            out.seek(0), err.seek(0)
            code = 0 if code is None else code if isinstance(code, int) else 1
            results[case_id] = {"returncode": code, "stdout": out.read(), "stderr": err.read()}
    return results


if __name__ == "__main__":  # python tests/contract_inputs.py CASES.json RESULTS.json
    import json

    todo = json.loads(Path(sys.argv[1]).read_text())
    Path(sys.argv[2]).write_text(json.dumps(run_in_process([tuple(c) for c in todo])))
