"""Where the live CMax engine's CPU time goes: tracking, global searches, one-rotation tests.

    python bench/cmax_cost.py EVENTS [--intrinsics 245 245 120 90] [--rounds 3] [--core 1]
        [--test-set iterations=2 --test-set max_events=2500] [--set track_events=5000]

Streams a recording through :class:`~spikegyro.cmax.live.CMaxEstimator` in 5 ms batches, in
process, pinned to one core, and prints the CPU time of the whole process, of the thread that
makes the estimates, and of each kind of work on whichever thread runs it (the tracking BFGS
refinements, the searches, the one-rotation tests), per second of events. ``--set`` and
``--test-set`` (``CMaxConfig`` and ``OneRotationTest`` fields) make a second configuration,
run alternately with the defaults in the same process, round by round, so that the two compare
on the same machine at the same time; the ratios are printed at the end.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import spikegyro.cmax.live as live
from spikegyro.cmax.config import CMaxConfig, OneRotationTest
from spikegyro.events.calib import PinholeCamera
from spikegyro.events.io import read_recording

KINDS = {"search": "search", "rotation_flags": "test", "refine": "tracking"}


def timed(function: Callable[..., Any], kind: str, spent: dict[str, float]) -> Callable:
    """``function``, adding the CPU time of the thread it runs on to ``spent[kind]``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.thread_time()
        try:
            return function(*args, **kwargs)
        finally:
            spent[kind] = spent.get(kind, 0.0) + time.thread_time() - start

    return wrapper


def settings(pairs: list[str], cls: type) -> dict[str, Any]:
    """``FIELD=VALUE`` pairs as keyword arguments of dataclass ``cls`` (values typed as its
    defaults)."""
    types = {f.name: type(f.default) for f in fields(cls)}
    out: dict[str, Any] = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in types or not value:
            raise ValueError(f"{pair!r}: expected FIELD=VALUE with a field of {cls.__name__}")
        if types[name] is bool:  # bool("False") is True
            out[name] = value.lower() in ("1", "true", "yes")
        else:
            out[name] = types[name](value)
    return out


def one_run(events: Any, camera: Any, config: CMaxConfig, spent: dict[str, float]) -> dict:
    """CPU seconds per second of events of one run: process, estimates' thread, each kind."""
    spent.clear()
    seconds = (int(events.t[-1]) - int(events.t[0])) / 1e6
    process, main = time.process_time(), time.thread_time()
    estimator = live.CMaxEstimator(camera, config)
    estimator.run(events, batch_us=5000)
    row = {"process": time.process_time() - process, "estimates' thread": time.thread_time() - main}
    row.update(spent)
    return {k: v / seconds for k, v in row.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("events", type=Path)
    parser.add_argument("--intrinsics", nargs=4, type=float)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--core", type=int, default=1)
    parser.add_argument("--set", action="append", default=[], help="CMaxConfig FIELD=VALUE")
    parser.add_argument("--test-set", action="append", default=[], help="OneRotationTest F=V")
    args = parser.parse_args()
    if not args.events.exists():
        parser.error(f"{args.events}: no such file")
    os.sched_setaffinity(0, {args.core})
    events = read_recording(args.events).events
    camera = None
    if args.intrinsics:
        camera = PinholeCamera(events.width, events.height, *args.intrinsics)
    spent: dict[str, float] = {}
    for name, kind in KINDS.items():
        setattr(live, name, timed(getattr(live, name), kind, spent))
    configs = {"defaults": CMaxConfig()}
    if args.set or args.test_set:
        try:
            test = OneRotationTest(**settings(args.test_set, OneRotationTest))
            config = CMaxConfig(**settings(args.set, CMaxConfig))
        except ValueError as error:
            parser.error(str(error))
        configs["set"] = replace(config, one_rotation=test)
    live.CMaxEstimator(camera).run(events.slice_time(int(events.t[0]), int(events.t[0]) + 200_000))
    rows: dict[str, list[dict]] = {name: [] for name in configs}
    for k in range(args.rounds):
        for name, config in configs.items():
            rows[name].append(one_run(events, camera, config, spent))
            row = rows[name][-1]
            print(
                f"round {k + 1} {name:8s} " + "  ".join(f"{key} {v:.3f}" for key, v in row.items())
            )
    if len(configs) == 2:
        for key in rows["defaults"][0]:
            ratio = [
                s.get(key, 0) / d[key] for d, s in zip(rows["defaults"], rows["set"], strict=True)
            ]
            print(f"{key}: set / defaults " + ", ".join(f"{r:.2f}" for r in ratio))
    print("CPU seconds per second of events, one core; searches and tests run on their own threads")


if __name__ == "__main__":
    main()
