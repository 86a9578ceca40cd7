"""Streaming SNN-6 on the event clock against the paper's 1 ms clock, at set event rates.

The same network (the shipped ``snn6`` weights, or ``--checkpoint``) streams the same events
through ``SNNEstimator`` (the exact event-driven engine on one thread, as ``predict`` runs it),
once per clock, alternating, on a simulated 240x180 rotation thinned to each event rate. The
event clock's rows are one per millisecond, like the paper clock's; its steps are fewer where
the events are few. Printed per rate: CPU seconds per second of events (one core; < 1 keeps up
with the camera), real time per CPU second, steps per second, and the ratio of the two clocks
measured in the same run.

    .venv/bin/python bench/clock_stream.py [--rates 0.1 1] [--clock events:1000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import itertools
import time
from typing import Any

import numpy as np

from spikegyro.events.core import EventArray
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.stream.engine import load_engine
from spikegyro.stream.predict import SNNEstimator, spec_with


def events_at_rate(rate_meps: float, duration_ms: int, seed: int) -> EventArray:
    """Simulated rotations at the paper's speeds over the same span, merged in time order until
    dense enough, then thinned at random to ``rate_meps`` million events per second."""
    parts: list[EventArray] = []
    need = int(rate_meps * 1e6 * duration_ms / 1000)
    while sum(len(p) for p in parts) < need:
        rec = simulate_sequence(SimConfig(duration_ms=duration_ms), len(parts), seed, "test")
        parts.append(rec.events)
    joined = EventArray.concatenate(parts)
    ev = joined[np.argsort(joined.t, kind="stable")]
    keep = np.random.default_rng(seed).choice(len(ev), size=need, replace=False)
    return ev[np.sort(keep)]


def run(engine: Any, spec: dict, events: EventArray, chunk_us: int = 10_000) -> tuple[float, int]:
    """CPU seconds to stream ``events`` in chunks of ``chunk_us`` and the steps run."""
    est = SNNEstimator(engine, spec)
    t0 = int(events.t[0]) // 1000 * 1000
    est.reset(t0)
    edges = np.searchsorted(events.t, np.arange(t0, int(events.t[-1]) + chunk_us, chunk_us))
    start = time.process_time()
    for a, b in itertools.pairwise(edges):
        est.update(events[a:b])
    est.finish(int(events.t[-1]) + 1)
    return time.process_time() - start, est.steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[0.1, 1.0], help="M events/s")
    parser.add_argument("--clock", default="events:1000", help="the event clock to compare")
    parser.add_argument("--checkpoint", default="snn6")
    parser.add_argument("--duration-ms", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=3, help="alternating rounds (best kept)")
    args = parser.parse_args()
    if args.repeat < 1 or args.duration_ms < 100 or min(args.rates) <= 0:
        parser.error("--repeat >= 1, --duration-ms >= 100 and rates > 0")
    engine, payload = load_engine(args.checkpoint)
    clocks = {"paper": spec_with(payload["input"], "paper"),
              args.clock: spec_with(payload["input"], args.clock)}  # fmt: skip
    print(f"{'M ev/s':>7} {'clock':>16} {'CPU s / s':>10} {'x real time':>12} {'steps/s':>8}")
    for rate in args.rates:
        events = events_at_rate(rate, args.duration_ms, seed=3)
        seconds = (int(events.t[-1]) - int(events.t[0])) / 1e6
        run(engine, clocks["paper"], events[: len(events) // 10])  # compile and warm up
        best: dict[str, tuple[float, int]] = {}
        for _ in range(args.repeat):
            for name, spec in clocks.items():
                cpu, steps = run(engine, spec, events)
                if name not in best or cpu < best[name][0]:
                    best[name] = (cpu, steps)
        for name, (cpu, steps) in best.items():
            print(f"{rate:7.2f} {name:>16} {cpu / seconds:10.3f} {seconds / cpu:12.2f} "
                  f"{steps / seconds:8.0f}")  # fmt: skip
        ratio = best["paper"][0] / best[args.clock][0]
        print(f"{rate:7.2f} {'event clock':>16} is {ratio:.2f}x the paper clock's speed")


if __name__ == "__main__":
    main()
