"""``predict`` on live sources, against a real stream: ``dv-processing``'s network server on
loopback, fed from a real recording at its own pace (:mod:`spikegyro.events.replay`), read by
spikegyro's own AEDAT 4 network reader. The estimates must be the file's, to the digit."""

from __future__ import annotations

import importlib.util
import multiprocessing
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from format_helpers import cli_error, cli_run

from spikegyro.events.blocks import ImuBlock
from spikegyro.events.core import EventArray
from spikegyro.stream.live import predict_live
from spikegyro.stream.writer import read_predictions

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
SHAPES = REAL / "unlabeled" / "ecd_shapes_start_mvtracking" / "events.txt"  # 0.79 s, 34,634
BOXES = REAL / "rueckauer2016_translBoxes" / "events.txt"  # 2.07 s, 162,771 events
needs_stream = pytest.mark.skipif(
    not SHAPES.is_file() or importlib.util.find_spec("dv_processing") is None,
    reason="needs ../shared/real and dv-processing (spikegyro[live])",
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(path: Path, url: str, speed: float = 1.0):
    from spikegyro.events.replay import start_replay

    return start_replay(path, url, packet_us=5000, speed=speed)


def predict_file(monkeypatch, capsys, path: Path, out: Path, *args: str) -> str:
    cli_run(monkeypatch, capsys, "predict", str(path), "--method", "cmax", "--out", str(out),
            *args)  # fmt: skip
    return out.read_text()


@needs_stream
def test_live_stream_gives_the_files_estimates(tmp_path, monkeypatch, capsys):
    url = f"dv://127.0.0.1:{free_port()}"
    server = serve(SHAPES, url)
    _, err = cli_run(monkeypatch, capsys, "predict", url, "--out", str(tmp_path / "live.csv"))
    server.join(10)
    assert "stopped at the stream's end" in err and "behind the stream" in err
    assert "contrast maximization" in err  # CMax by default for a live source
    want = predict_file(monkeypatch, capsys, SHAPES, tmp_path / "file.csv")
    live = (tmp_path / "live.csv").read_text()
    assert live.count("\n") > 60  # 0.79 s at 100 Hz
    assert live == want


@needs_stream
def test_live_snn_on_the_event_clock_gives_the_files_rows(tmp_path, monkeypatch, capsys):
    """The network on the event clock, served over loopback in packets of 5 ms: its rows (one
    per ms, each holding the latest step) are the file's, to the digit, wherever the packets
    cut the steps."""
    snn = ["--method", "snn", "--checkpoint", "snn6-real", "--intrinsics", "199", "199", "132",
           "110"]  # fmt: skip
    url = f"dv://127.0.0.1:{free_port()}"
    server = serve(SHAPES, url)
    cli_run(monkeypatch, capsys, "predict", url, *snn, "--out", str(tmp_path / "live.csv"))
    server.join(10)
    cli_run(monkeypatch, capsys, "predict", str(SHAPES), *snn, "--out", str(tmp_path / "file.csv"))
    live, want = (read_predictions(tmp_path / f) for f in ("live.csv", "file.csv"))
    assert "step_ms" in live and len(live["t_us"]) > 500  # 0.79 s, a row per ms
    assert np.abs(live["omega"]).max() > 0 and len(np.unique(live["step_ms"])) > 10
    n = len(live["t_us"])  # the live run stops at the stream's last event, the file at its end
    assert np.array_equal(live["t_us"] - live["t_us"][0], want["t_us"][:n] - want["t_us"][0])
    np.testing.assert_array_equal(live["omega"], want["omega"][:n])
    np.testing.assert_array_equal(live["step_ms"], want["step_ms"][:n])


@needs_stream
def test_unix_socket_to_stdout_until_end(tmp_path, monkeypatch, capsys):
    url = f"dv://{tmp_path / 'dv.sock'}"
    server = serve(SHAPES, url, speed=4.0)
    out, err = cli_run(monkeypatch, capsys, "predict", url, "--end", "0.3", "--out", "-")
    server.join(10)
    want = predict_file(monkeypatch, capsys, SHAPES, tmp_path / "file.csv", "--end", "0.3")
    times = [float(line.split(",")[0]) for line in out.splitlines()[1:]]
    assert out == want and len(times) > 10 and times[-1] == 0.3  # first event at 0 s
    assert "estimates" in err and "t,wx" not in err


def capture(path: Path) -> bytes:
    """The bytes of ``path`` served by dv-processing, as they come over the socket."""
    url = f"dv://127.0.0.1:{free_port()}"
    server = serve(path, url, speed=20.0)
    data = bytearray()
    with socket.create_connection(("127.0.0.1", int(url.rsplit(":", 1)[1]))) as sock:
        while chunk := sock.recv(1 << 16):
            data += chunk
    server.join(10)
    return bytes(data)


def send_bytes(listener: socket.socket, data: bytes) -> None:
    connection, _ = listener.accept()
    connection.sendall(data)
    connection.close()


@needs_stream
def test_stream_cut_mid_packet(tmp_path, monkeypatch, capsys):
    data = capture(SHAPES)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    cut = len(data) * 2 // 3 + 5  # inside a packet (its header is 8 bytes, its events 16)
    sender = multiprocessing.get_context("fork").Process(
        target=send_bytes, args=(listener, data[:cut])
    )
    sender.start()
    url = f"dv://127.0.0.1:{listener.getsockname()[1]}"
    _, err = cli_run(monkeypatch, capsys, "predict", url, "--out", str(tmp_path / "cut.csv"))
    sender.join(10)
    listener.close()
    assert "ended" in err and "bytes into a packet" in err
    got = (tmp_path / "cut.csv").read_text().splitlines()
    want = predict_file(monkeypatch, capsys, SHAPES, tmp_path / "file.csv").splitlines()
    assert 20 < len(got) < len(want)
    assert got[:-1] == want[: len(got) - 1]  # the last may miss events of the lost packet


@needs_stream
def test_ctrl_c_writes_what_was_estimated(tmp_path):
    url = f"dv://127.0.0.1:{free_port()}"
    server = serve(BOXES, url)
    out = tmp_path / "pred.csv"
    # As from a terminal: a test runner started in the background by a shell without job
    # control ignores SIGINT, and a child would inherit that (Python then installs no handler).
    run = subprocess.Popen(
        [sys.executable, "-m", "spikegyro", "predict", url, "--out", str(out)],
        stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    seen = ""
    while "Ctrl-C stops" not in seen:  # reading the stream (imports and set-up are done)
        seen += run.stderr.readline()
    time.sleep(1.0)
    run.send_signal(signal.SIGINT)
    _, err = run.communicate(timeout=60)
    err = seen + err
    server.kill()
    assert run.returncode == 130, err
    assert "stopped at Ctrl-C" in err and "interrupted" in err
    rows = read_predictions(out)["t_us"]
    assert 0 < len(rows) < 200  # estimates up to the Ctrl-C, of a 2.07 s stream at 100 Hz


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["ftp://x"], "unknown source"),
        (["dv://127.0.0.1"], "dv://HOST:PORT"),
        (["dv://127.0.0.1:1"], "cannot connect"),
        (["dv://127.0.0.1:1", "--gyro", "gyro.txt"], "--gyro"),
        (["dv://127.0.0.1:1", "--width", "240", "--height", "180"], "sensor size"),
        (["dv://127.0.0.1:1", "--imu-to-camera", "x,x,z"], "exactly once"),
        (["dv://127.0.0.1:1", "--method", "snn", "--window-ms", "5"], "--window-ms"),
        (["dv://127.0.0.1:1", "--offline"], "--offline"),
    ],
)
def test_bad_live_options(tmp_path, monkeypatch, capsys, args, words):
    out = tmp_path / "pred.csv"
    err = cli_error(monkeypatch, capsys, "predict", *args, "--out", str(out))
    assert words in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_camera_without_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "dv_processing", None)  # as if not installed
    err = cli_error(monkeypatch, capsys, "predict", "camera://", "--out", str(tmp_path / "p.csv"))
    assert "spikegyro[live]" in err and list(tmp_path.iterdir()) == []


def test_imu_to_camera_checked_without_a_gyro(tmp_path, monkeypatch, capsys):
    events = tmp_path / "events.txt"
    events.write_text("0.0 1 2 1\n0.001 3 4 0\n")
    err = cli_error(monkeypatch, capsys, "predict", str(events), "--imu-to-camera", "x,x,z",
                    "--out", str(tmp_path / "p.csv"))  # fmt: skip
    assert "exactly once" in err and sorted(p.name for p in tmp_path.iterdir()) == ["events.txt"]


class ScriptedSource:
    """A live source with an IMU (a camera's path after ``dv-processing``), from arrays."""

    name, sensor, has_imu, truncated = "camera://test", (240, 180), True, 0

    def __init__(self, items):
        self.items = items

    def batches(self):
        yield from self.items

    def close(self):
        pass


class Every5ms:
    """An estimator with one estimate per 5 ms of events: ω = (the batch's event count, 0, 0)."""

    label, confidence = "test", False

    def reset(self, t0_us=None):
        self.t0, self.done = t0_us, 0

    def update(self, events):
        from spikegyro.stream.estimator import Estimates, output_times

        t = output_times(self.t0, 200.0, self.done, int(events.t[-1]) - 1)
        self.done += len(t)
        return Estimates(t, np.column_stack([np.full(len(t), len(events)), np.zeros((len(t), 2))]))

    def finish(self, t_end_us):
        from spikegyro.stream.estimator import Estimates

        return Estimates.empty()


def test_the_streams_imu_is_the_reference(tmp_path):
    def events(t0):
        t = np.arange(t0, t0 + 5000, 500)
        return EventArray.from_arrays(t % 240, t % 180, t, t % 2, 240, 180)

    # the IMU in its own axes: ω_imu = (0, 1, 0) rad/s, y_imu = x_camera ('y,-x,z')
    imu = ImuBlock(t=np.arange(0, 40_000, 1000), omega=np.tile([0.0, 1.0, 0.0], (40, 1)))
    items = [imu] + [events(t0) for t0 in range(0, 30_000, 5000)]
    rotation = np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])
    live = predict_live(ScriptedSource(items), Every5ms(), tmp_path / "p.csv",
                        gyro_rotation=rotation, notify=lambda line: None)  # fmt: skip
    got = read_predictions(tmp_path / "p.csv")
    np.testing.assert_array_equal(got["t_us"], np.arange(5000, 30_000, 5000))
    np.testing.assert_allclose(got["gyro_omega"], np.tile([1.0, 0.0, 0.0], (5, 1)))
    assert live.run.estimates == 5 and live.run.events == 60 and not live.interrupted
