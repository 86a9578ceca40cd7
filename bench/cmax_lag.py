"""Live CMax against offline CMax, each scored at its estimates' own timestamps.

    .venv/bin/python bench/cmax_lag.py --translboxes ../shared/real/rueckauer2016_translBoxes \
        --sim-dir /tmp/cmax-lag [--sims slow demo] [--seconds 0.6] [--accelerating] \
        [--shapes ../shared/real/ecd_windows/shapes_rotation] \
        [--rotbars ../shared/real/unlabeled/davis240_rotbars/events.txt]

Streams each recording through :class:`~spikegyro.cmax.live.CMaxEstimator` at its defaults
(100 Hz, causal windows: each estimate uses only events up to its time) and runs the offline
engine (:func:`~spikegyro.cmax.offline.estimate_offline`, windows centred on each estimate's
time) over it, in the same run; ``--accelerating`` adds the live engine with
``accelerating=True`` (a rate changing linearly over the window, ω reported at the window's
end). Every estimate is scored against the gyro interpolated at its own timestamp (from 50 ms
on): per-axis mean absolute error and mean Euclidean error, deg/s, the median age of the
events behind it (the window's lag, ms), the share of estimates with ``ill_posed`` bit 4 and
CPU-seconds per second of events. The last line of each recording is the ratio of the live
error to the offline one.

Recordings: translBoxes (real DAVIS240C, its own gyro in the camera frame, whose +3.5 deg/s
tilt and -1 deg/s pan bias from its README are subtracted), and two simulated DAVIS240C-like
recordings with changing rotation, written once to ``--sim-dir`` and reused: ``slow`` (2 s, a
hand-held-like rotation, ``spikegyro simulate --slow-share 1 --duration-ms 2000``'s
trajectory) and ``demo`` (4 s, the trajectory the demo streams: ``accel_std_deg=300``).
``--shapes``: the real ECD ``shapes_rotation`` window (106 ms of fast rotation, its
``calib.txt``), against its motion capture (good to about ±20 deg/s). ``--rotbars``: the real
DAVIS240 ``rot_bars`` recording from 5.43 s on (fx = fy = 245 px, c = (120, 90)), which has no
gyro: the offline engine is its reference, so only the live row is scored. ``--seconds``
scores only the first that many seconds of each (speed on a loaded machine).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time
from pathlib import Path

import numpy as np

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.offline import estimate_offline
from spikegyro.cmax.problem import camera_from_attrs
from spikegyro.events.calib import Calibration, load_calibration
from spikegyro.events.io import read_recording, write_recording
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.sim.trajectory import TrajectoryConfig
from spikegyro.stream.estimator import ILL_NOT_ONE_ROTATION

SIMULATED = {
    "slow": (SimConfig(duration_ms=2000, trajectory=TrajectoryConfig(slow_share=1.0)), 11),
    "demo": (SimConfig(duration_ms=4000, trajectory=TrajectoryConfig(accel_std_deg=300.0)), 2027),
}


def simulated(folder: Path, name: str):
    """The simulated recording ``name`` (written to ``folder`` the first time)."""
    path = folder / f"{name}.h5"
    if not path.exists():
        sim, seed = SIMULATED[name]
        folder.mkdir(parents=True, exist_ok=True)
        write_recording(path, simulate_sequence(sim, 0, seed, split="test"))
    return read_recording(path)


def run(engine: str, events, camera):
    """Estimates of ``engine`` (live, accelerating, offline) over the events, and CPU-s."""
    c0 = time.process_time()
    if engine == "offline":
        out = estimate_offline(events, camera)
    else:
        est = CMaxEstimator(camera, CMaxConfig(accelerating=engine == "accelerating"))
        out = est.run(events)
    return out, time.process_time() - c0


def score(events, camera, t_gyro, w_gyro, engine: str) -> dict:
    """One engine's estimates scored at each estimate's own timestamp (deg/s)."""
    out, cpu = run(engine, events, camera)
    seconds = (int(events.t[-1]) - int(events.t[0])) / 1e6
    t0 = int(events.t[0]) // 1000 * 1000
    ok = (out.t_us > t0 + 50_000) & (out.t_us >= t_gyro[0]) & (out.t_us <= t_gyro[-1])
    ref = np.column_stack([np.interp(out.t_us[ok], t_gyro, w_gyro[:, i]) for i in range(3)])
    err = np.degrees(out.omega[ok] - ref)
    return {
        "mae": np.abs(err).mean(axis=0),
        "euclid": float(np.linalg.norm(err, axis=1).mean()),
        "speed": float(np.degrees(np.linalg.norm(ref, axis=1)).mean()),
        "age": float(np.nanmedian(out.delay_us[ok])) / 1e3,
        "bit4": float(((out.ill_posed[ok] & ILL_NOT_ONE_ROTATION) > 0).mean()),
        "n": int(ok.sum()),
        "cpu": cpu / seconds,
    }


def recordings(args: argparse.Namespace):
    """(name, events, camera, gyro times µs, gyro ω rad/s) of each recording benchmarked; the
    gyro is None where the offline engine is the reference."""
    if args.translboxes is not None:
        rec = read_recording(args.translboxes / "events.txt")
        gyro = np.loadtxt(args.translboxes / "gyro.txt")
        bias = np.radians([3.5, -1.0, 0.0])
        camera = Calibration(245.0, 245.0, 120.0, 90.0)
        yield "translBoxes", rec.events, camera, gyro[:, 0] * 1e6, gyro[:, 1:4] - bias
    if args.shapes is not None:
        events = read_recording(args.shapes / "events.txt").events
        mocap = np.loadtxt(args.shapes / "gyro_from_mocap.txt")
        camera = load_calibration(args.shapes / "calib.txt")
        yield "ECD shapes", events, camera, np.rint(mocap[:, 0] * 1e6), mocap[:, 1:4]
    if args.rotbars is not None:
        events = read_recording(args.rotbars).events
        events = events.slice_time(int(events.t[0] + 5.43e6), int(events.t[-1]) + 1)
        yield "rot_bars tail", events, Calibration(245.0, 245.0, 120.0, 90.0), None, None
    for name in args.sims if args.sim_dir is not None else ():
        rec = simulated(args.sim_dir, name)
        camera = camera_from_attrs(rec.attrs, rec.events.width, rec.events.height)
        yield f"sim {name}", rec.events, camera, rec.gyro.t.astype(np.float64), rec.gyro.omega


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--translboxes", type=Path, help="The translBoxes folder (gyro.txt).")
    parser.add_argument("--sim-dir", type=Path, help="Folder for the simulated recordings.")
    parser.add_argument("--sims", nargs="+", default=list(SIMULATED), choices=list(SIMULATED))
    parser.add_argument("--seconds", type=float, default=0.0, help="Score only this long (s).")
    parser.add_argument("--accelerating", action="store_true", help="Also accelerating=True.")
    parser.add_argument("--shapes", type=Path, help="The ECD shapes_rotation folder.")
    parser.add_argument("--rotbars", type=Path, help="rot_bars' events.txt.")
    args = parser.parse_args()
    engines = ["live"] + (["accelerating"] if args.accelerating else []) + ["offline"]
    print(
        "recording     |ω|    engine          n   tilt   pan  roll  Euclid  age ms  bit 4  CPU-s/s"
    )
    for name, events, camera, t_gyro, w_gyro in recordings(args):
        if args.seconds > 0:
            events = events.slice_time(int(events.t[0]), int(events.t[0] + args.seconds * 1e6))
        rows = {}
        if t_gyro is None:  # the offline engine is the reference
            ref, _ = run("offline", events, camera)
            t_gyro, w_gyro = ref.t_us.astype(np.float64), ref.omega
            rows["offline"] = None
        for engine in engines:
            if engine not in rows:
                rows[engine] = score(events, camera, t_gyro, w_gyro, engine)
        for engine, r in rows.items():
            if r is None:
                print(f"{name:13s}        offline       (the reference)")
                continue
            tilt, pan, roll = r["mae"]
            print(f"{name:13s} {r['speed']:5.1f}  {engine:13s} {r['n']:4d} {tilt:5.2f} {pan:5.2f} "
                  f"{roll:5.2f}  {r['euclid']:6.2f}  {r['age']:6.1f}  {100 * r['bit4']:4.0f}%  "
                  f"{r['cpu']:6.2f}")  # fmt: skip
        if rows["offline"] is not None:
            print(f"{name:13s} live / offline Euclidean error: "
                  f"{rows['live']['euclid'] / rows['offline']['euclid']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
