"""Ctrl-C means stop: a real SIGINT to ``spikegyro`` in a subprocess ends it with exit code 130,
one line on stderr and no traceback; outputs are complete or absent (``train`` keeps the
validated checkpoint it writes on the way out).

Each command gets a recording long enough that it is still at work when the signal comes: once
its output's temporary file exists (``predict``), once ``train`` logs, or once it has used enough
CPU time to be past its imports and into its compiled loops (``baseline cmax``,
``evaluate-real``).
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from contract_inputs import cpu_seconds, interrupt_after, recording, spikegyro

from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording
from spikegyro.models.registry import load_checkpoint


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s of events: minutes of work for every command here."""
    return write_recording(tmp_path_factory.mktemp("long") / "long.h5", recording(20_000, 30))


def _assert_stopped(done, folder: Path, absent: list[str]) -> None:
    assert done.returncode == 130, done.stderr[-2000:]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert lines[-1] == "interrupted (Ctrl-C); stopped.", done.stderr[-2000:]
    names = sorted(p.name for p in folder.iterdir())
    assert not [n for n in names if n in absent or n.startswith(".")], names


def test_ctrl_c_stops_predict_and_leaves_no_output(long_recording, tmp_path) -> None:
    out = tmp_path / "pred.csv"

    def writing(_pid: int) -> bool:  # the prediction file is open under its temporary name
        return any(tmp_path.glob(".pred.csv.*"))

    done = interrupt_after(spikegyro("predict", str(long_recording), "--out", str(out)),
                           writing, cwd=tmp_path)  # fmt: skip
    _assert_stopped(done, tmp_path, ["pred.csv"])


@pytest.mark.parametrize("command", [["baseline", "cmax"], ["evaluate-real"]])
def test_ctrl_c_inside_compiled_code_is_exit_130_not_a_system_error(
    command, long_recording, tmp_path
) -> None:
    out = tmp_path / ("r" if command == ["evaluate-real"] else "c.csv")
    done = interrupt_after(
        spikegyro(*command, str(long_recording), "--out", str(out)),
        lambda pid: cpu_seconds(pid) > 8.0,  # past the imports and the file read
        cwd=tmp_path,
    )
    assert "SystemError" not in done.stderr
    _assert_stopped(done, tmp_path, [out.name])


def _run_script(script: Path) -> subprocess.CompletedProcess:
    """Run a Python script with Ctrl-C's default action (a test run started in the background
    would hand it an ignored SIGINT)."""
    return subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _tiny_dataset(root: Path) -> Path:
    rng = np.random.default_rng(0)
    for i, split in enumerate(("train", "train", "val")):
        n, ms = 5000, 100
        t = np.sort(rng.integers(0, ms * 1000, n))
        xy = rng.integers(0, 64, (2, n))
        events = EventArray.from_arrays(xy[0], xy[1], t, rng.integers(0, 2, n), 64, 64)
        gyro_t = np.arange(0, ms * 1000 + 1, 1000)
        gyro = GyroTrace.from_arrays(gyro_t, rng.standard_normal((gyro_t.size, 3)))
        write_recording(root / split / f"seq_{i:06d}.h5", Recording(events, gyro))
    return root


def test_ctrl_c_stops_train_with_a_validated_checkpoint(tmp_path) -> None:
    data, run = _tiny_dataset(tmp_path / "data"), tmp_path / "run"
    options = (
        "--preset cpu --scale 1 --sensor-width 64 --sensor-height 64 --window-ms 40 "
        "--loss-start-step 20 --batch-size 1 --iterations 100000 --val-every 100000 "
        "--log-every 1 --num-workers 0 --device cpu --bare-steps 0 --val-windows 1"
    )

    def training(_pid: int) -> bool:  # a step is logged: the graceful stop is armed
        log = run / "log.csv"
        return log.exists() and len(log.read_text().splitlines()) > 1

    done = interrupt_after(
        spikegyro("train", "--data", str(data), "--out", str(run), *options.split()),
        training,
        cwd=tmp_path,
    )
    assert done.returncode == 130, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert "continue with: spikegyro train" in done.stdout
    _model, payload = load_checkpoint(run / "last.pt")
    assert payload["model"] == "snn6"
    assert not [p.name for p in run.iterdir() if p.name.startswith(".")]


def test_a_ctrl_c_that_compiled_code_swallows_still_stops_without_a_traceback(tmp_path) -> None:
    """Numba's JIT writes its cache from a ctypes callback (llvmlite), where a KeyboardInterrupt
    is printed and dropped: on a fresh install, a Ctrl-C then let ``predict`` run to the end.
    The handler remembers it, so the next check in a long loop raises it again."""
    script = tmp_path / "swallow.py"
    script.write_text(
        "import ctypes, os, signal\n"
        "from spikegyro.errors import check_interrupt, install_sigint_handler\n"
        "install_sigint_handler()\n"
        "def callback():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    sum(range(10_000))\n"
        "ctypes.CFUNCTYPE(None)(callback)()\n"
        "print('survived')\n"
        "check_interrupt()\n"
        "print('not stopped')\n"
    )
    done = _run_script(script)
    assert done.stdout.split() == ["survived"], done.stdout
    assert "KeyboardInterrupt" in done.stderr  # raised again by check_interrupt, uncaught here
    assert "ctypes callback" not in done.stderr  # the swallowed one is not printed


def test_an_error_after_a_swallowed_ctrl_c_is_reported_as_the_interrupt(tmp_path) -> None:
    """A Ctrl-C that cuts Numba's compiler short can surface as another error (its cache save
    finds no object code: RuntimeError) before any check: that is still Ctrl-C, exit 130 with
    one line, not a traceback and exit 1."""
    script = tmp_path / "cut_short.py"
    script.write_text(
        "import ctypes, os, signal\n"
        "from spikegyro import cli\n"
        "def compile_step():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    sum(range(10_000))\n"
        "def boom():\n"
        "    ctypes.CFUNCTYPE(None)(compile_step)()\n"
        "    raise RuntimeError('no compiled object yet')\n"
        "cli._COMMANDS['boom'] = '__main__:boom'\n"
        "cli.sys.argv = ['spikegyro', 'boom']\n"
        "cli.main()\n"
    )
    done = _run_script(script)
    assert done.returncode == 130, done.stderr[-2000:]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.strip().splitlines()[-1] == "interrupted (Ctrl-C); stopped."
