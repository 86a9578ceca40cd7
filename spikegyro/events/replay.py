"""Serve a recording as a live DV network stream, at its own pace: ``predict dv://...`` (or any
AEDAT 4 network client) without a camera.

:func:`replay` runs ``dv-processing``'s network server (extra ``spikegyro[live]``) on a TCP
address or a UNIX socket, waits for a client, then sends the file's events in packets of
``packet_us`` of event time, each once its last moment has passed on the wall clock (as a camera
sends them), and returns the wall time at which each packet was sent. Start it in its own
process (:func:`start_replay`): ``dv-processing``'s server cannot be closed while a client is
connected, so the process exits when the stream is sent, which ends the stream for the client.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from spikegyro.events.blocks import optional_import
from spikegyro.events.io import read_recording
from spikegyro.events.sources import EXTRA, parse_url


def _packets(
    dv: Any, path: str | os.PathLike, packet_us: int
) -> tuple[list[Any], np.ndarray, tuple[int, int]]:
    """The recording's events as ``dv-processing`` event stores of ``packet_us`` each, each
    packet's end (µs, event time) and the sensor size."""
    ev = read_recording(path).events
    ends = np.arange(int(ev.t[0]) + packet_us, int(ev.t[-1]) + packet_us + 1, packet_us)
    cuts = np.searchsorted(ev.t, ends, side="left")
    stores, lo = [], 0
    for hi in cuts:
        store = dv.EventStore()
        for t, x, y, p in zip(ev.t[lo:hi].tolist(), ev.x[lo:hi].tolist(), ev.y[lo:hi].tolist(),
                              ev.p[lo:hi].tolist(), strict=True):  # fmt: skip
            store.push_back(t, x, y, bool(p))
        stores.append(store)
        lo = hi
    return stores, ends, ev.sensor_size


def replay(
    path: str | os.PathLike,
    url: str,
    packet_us: int = 5000,
    speed: float = 1.0,
    wait_s: float = 30.0,
    listening: Any = None,
    done: Callable[[np.ndarray], None] | None = None,
) -> np.ndarray:
    """Serve ``path`` on ``url`` (``dv://HOST:PORT`` or ``dv:///socket/path``) to the first
    client, ``speed`` times real time; returns each packet's send time (``time.time()``, s).
    ``listening`` (an ``Event``) is set once the server accepts connections; ``done`` is called
    with the send times while the server still runs (it should end the process: see the
    module)."""
    dv = optional_import("dv_processing", EXTRA, url)
    where = parse_url(url)
    stores, ends, sensor = _packets(dv, path, packet_us)
    stream = dv.io.Stream.EventStream(0, "events", f"replay_{Path(path).name}", sensor)
    if where.path:
        server = dv.io.NetworkWriter(dv.Path(where.path), stream)
    else:
        server = dv.io.NetworkWriter(where.host, where.port, stream)
    if listening is not None:
        listening.set()
    deadline = time.time() + wait_s
    while server.getClientCount() == 0 and time.time() < deadline:
        time.sleep(0.001)
    sent = np.zeros(len(stores))
    start, t_first = time.time(), ends[0] - packet_us
    for k, store in enumerate(stores):
        due = start + (ends[k] - t_first) / 1e6 / speed
        while (now := time.time()) < due:
            time.sleep(min(due - now, 0.0005))
        if store.size():
            server.writeEvents(store)
        sent[k] = time.time()
    while server.getQueuedPacketCount():
        time.sleep(0.001)
    time.sleep(0.05)  # the last packet leaves the socket
    if done is not None:
        done(sent)
    return sent


def _serve(
    path: str, url: str, packet_us: int, speed: float, log: str | None, listening: Any
) -> None:
    def exit_process(sent: np.ndarray) -> None:
        if log:
            np.save(log, sent)
        os._exit(0)  # with the server open: closing it while a client is connected blocks

    replay(path, url, packet_us, speed, listening=listening, done=exit_process)


def start_replay(
    path: str | os.PathLike,
    url: str,
    packet_us: int = 5000,
    speed: float = 1.0,
    sent_log: str | os.PathLike | None = None,
) -> multiprocessing.Process:
    """:func:`replay` in a new process, returned once its server listens (join it);
    ``sent_log``: a ``.npy`` file to save the packets' send times in."""
    context = multiprocessing.get_context("spawn")
    listening = context.Event()
    log = None if sent_log is None else str(sent_log)
    process = context.Process(
        target=_serve, args=(str(path), url, packet_us, speed, log, listening), daemon=True
    )
    process.start()
    while not listening.wait(0.05):
        if not process.is_alive():
            raise RuntimeError(f"the replay of {path} on {url} ended before it listened")
    return process
