"""Contrast maximization's live engine at about 5-9 M events/s from a megapixel, real texture.

    .venv/bin/python bench/cmax_upsampled.py \
        --events ../shared/real/unlabeled/davis240_rotbars/events.txt \
        [--speedup 3] [--block 5] [--seconds 0] [--repeat 1]

A real DAVIS240 recording of a camera rotating before bars (mostly roll; calibration fx = fy =
245 px, c = (120, 90)) is made into a megapixel stream of the same scene: every event is copied
onto the ``block`` x ``block`` pixels its pixel covers on a sensor ``block`` times larger
(1200x900 for 5; intrinsics scaled by ``block``, the principal point moved to the block's
centre; the copies share the event's time), and the stream is played ``speedup`` times faster
(event times divided by ``speedup``: ω multiplied by it). Nothing is written to disk.

References: the offline engine (:func:`~spikegyro.cmax.offline.estimate_offline`) and the live
engine (100 Hz, defaults) on the original 240x180 recording, their ω multiplied by ``speedup``
and their times divided by it. The live engine's run on the original is also the baseline of
cost, measured in the same run. The fast megapixel stream is scored against both at its
estimates' own times (from 0.3 s of the original's time on, where the references have
settled): against the offline one, the live engine's error as a gyroscope on this recording
(the live engine on the original is scored against it too); against the live one, what the
megapixel and the rate change in the estimates (thinning, binning, windows). Cost: CPU seconds
(the estimates on one thread; searches and tests on threads of their own, counted too) per
second of events. Printed: event rates, roll error relative to the roll rate (mean absolute
error over mean |roll|) and the whole ω's mean Euclidean error relative to the mean |ω|,
CPU-seconds per second, and the megapixel stream's ratios to the baseline's.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.offline import estimate_offline
from spikegyro.events.calib import Calibration
from spikegyro.events.core import EventArray
from spikegyro.events.io import read_recording
from spikegyro.stream.estimator import Estimates

CALIBRATION = (245.0, 245.0, 120.0, 90.0)  # fx, fy, cx, cy of the DAVIS240 recording, px
SETTLE_S = 0.3  # the reference's first estimates come from its first search: not scored


def upsampled(events: EventArray, block: int, speedup: float) -> EventArray:
    """Each event copied onto the ``block`` x ``block`` pixels of a ``block`` times larger
    sensor, in time order, times (µs) divided by ``speedup``."""
    k = block * block
    dx, dy = np.divmod(np.arange(k), block)
    x = (events.x.astype(np.int32)[:, None] * block + dx).ravel()
    y = (events.y.astype(np.int32)[:, None] * block + dy).ravel()
    t = np.repeat(np.rint((events.t - events.t[0]) / speedup).astype(np.int64), k)
    p = np.repeat(events.p, k)
    width, height = events.width * block, events.height * block
    return EventArray(x.astype(np.int16), y.astype(np.int16), t, p, width, height)


def scaled_camera(block: int) -> Calibration:
    """The calibration of the ``block`` times larger sensor: pixel u of the original covers
    ``block u .. block u + block - 1``, whose centre is ``block u + (block - 1) / 2``."""
    fx, fy, cx, cy = CALIBRATION
    half = (block - 1) / 2.0
    return Calibration(block * fx, block * fy, block * cx + half, block * cy + half)


def live(events: EventArray, camera: Calibration, repeat: int) -> tuple[Estimates, float]:
    """The live engine's estimates over ``events`` (batches of 10 ms of event time, as a driver
    delivers) and its CPU seconds per second of events: the least of ``repeat`` runs."""
    best, out = np.inf, Estimates.empty()
    seconds = (int(events.t[-1]) - int(events.t[0])) / 1e6
    for _ in range(repeat):
        est = CMaxEstimator(camera)
        c0 = time.process_time()
        out = est.run(events, batch_us=10_000)
        best = min(best, (time.process_time() - c0) / seconds)
    return out, best


def score(out: Estimates, ref: Estimates, speedup: float, t0_us: int) -> dict:
    """Errors of ``out`` against the reference ``ref`` (of the original stream, starting at
    ``t0_us``) played ``speedup`` times faster, at the estimates' own times."""
    t_ref = (ref.t_us - t0_us) / speedup
    w_ref = ref.omega * speedup
    t = out.t_us - (t0_us if speedup == 1 else 0)
    ok = (t >= SETTLE_S * 1e6 / speedup) & (t >= t_ref[0]) & (t <= t_ref[-1])
    truth = np.column_stack([np.interp(t[ok], t_ref, w_ref[:, i]) for i in range(3)])
    err = np.degrees(out.omega[ok] - truth)
    speed = np.degrees(np.linalg.norm(truth, axis=1)).mean()
    roll = np.degrees(np.abs(truth[:, 2])).mean()
    return {
        "n": int(ok.sum()),
        "roll_dps": float(roll),
        "roll_rel": float(np.abs(err[:, 2]).mean() / roll),
        "rel": float(np.linalg.norm(err, axis=1).mean() / speed),
        "mae": np.abs(err).mean(axis=0),
    }


def rates(events: EventArray) -> tuple[float, float]:
    """Mean event rate (events/s) and that of the busiest 100 ms (M events/s)."""
    t = events.t - events.t[0]
    per = np.bincount(t // 100_000) / 0.1 / 1e6
    return len(events) / max(int(t[-1]), 1) * 1e6, float(per.max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=Path, required=True, help="The rot_bars events.txt.")
    parser.add_argument("--speedup", type=float, default=3.0, help="Play this many times faster.")
    parser.add_argument("--block", type=int, default=5, help="Copies per pixel side.")
    parser.add_argument("--seconds", type=float, default=0.0, help="Only this much (s; 0: all).")
    parser.add_argument("--repeat", type=int, default=1, help="Live runs; the least CPU kept.")
    args = parser.parse_args()
    rec = read_recording(args.events)
    events = replace(rec.events, width=240, height=180)
    if args.seconds > 0:
        events = events.slice_time(int(events.t[0]), int(events.t[0] + args.seconds * 1e6))
    camera = Calibration(*CALIBRATION)
    c0 = time.process_time()
    ref = estimate_offline(events, camera)
    print(f"reference: offline, 240x180, {len(ref.t_us)} estimates, "
          f"{time.process_time() - c0:.0f} CPU-s")  # fmt: skip
    fast = upsampled(events, args.block, args.speedup)
    base, base_cpu = live(events, camera, args.repeat)
    big, big_cpu = live(fast, scaled_camera(args.block), args.repeat)
    t0 = int(events.t[0])
    label = f"{fast.width}x{fast.height} x{args.speedup:g}"
    rows = [
        ("240x180 x1", "offline", score(base, ref, 1.0, t0), events, base_cpu),
        (label, "offline", score(big, ref, args.speedup, t0), fast, big_cpu),
        (label, "live 240x180", score(big, base, args.speedup, t0), fast, big_cpu),
    ]
    for name, against, r, stream, cpu in rows:
        mean, peak = rates(stream)
        tilt, pan, roll = r["mae"]
        print(f"{name:14s} {mean / 1e6:5.2f} M ev/s (busiest 100 ms {peak:5.2f})  vs "
              f"{against:12s} n={r['n']:4d}  |roll| {r['roll_dps']:6.1f} deg/s  MAE {tilt:6.2f} "
              f"{pan:6.2f} {roll:6.2f}  roll/rate {100 * r['roll_rel']:5.1f} %  Euclid/|w| "
              f"{100 * r['rel']:5.1f} %  CPU-s/s {cpu:5.2f} (real time {1 / cpu:4.2f}x)",
              flush=True)  # fmt: skip
    ratio = rates(fast)[0] / rates(events)[0]
    print(f"megapixel x{args.speedup:g} over the original: events/s {ratio:.1f}x, CPU-s/s "
          f"{big_cpu / base_cpu:.2f}x, roll/rate vs offline "
          f"{rows[1][2]['roll_rel'] / rows[0][2]['roll_rel']:.2f}x")  # fmt: skip
    print(f"load average: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
