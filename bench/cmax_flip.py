"""Contrast maximization's live engine on simulated quadrotor flips (DVS128-like sensor).

    .venv/bin/python bench/cmax_flip.py [--sequences 4] [--out /tmp/cmax-flips]

Each flip is ``spikegyro simulate --trajectory flip`` (a 360 deg roll in 600 ms, raised-cosine
rate peaking at 1,200 deg/s, centred in 800 ms, over tilt and pan drifting at N(0, 10²) deg/s)
on a 128x128 sensor with f = 115 px and the principal point at its centre, with the ideal
sensor (``ideal``) and with the noisy DAVIS-like sensor model (``davis240c``: background
activity while the camera hovers), ``--sequences`` of each (test split, indices 0..N-1, seed
0), written once to ``--out`` and reused.

The live engine (100 Hz) runs on each with its defaults and, in the same run, with windows
sized by the estimates alone (``WindowPolicy(rate_events=0)``: the engine before
windows followed the event rate). Printed per flip and engine: the roll rate integrated over
the estimates (held on the 1 ms grid until the next estimate, 0 before the first; and by the
trapezoid over the estimates' times) against the known 360 deg, the mean absolute roll error
of the estimates against the known rate at their own times, the first estimate's time, and CPU
seconds per second of events.
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
from spikegyro.cmax.problem import camera_from_attrs
from spikegyro.cmax.windows import WindowPolicy
from spikegyro.events.core import Recording
from spikegyro.events.io import read_recording, write_recording
from spikegyro.sim.camera import Camera
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.sim.trajectory import TrajectoryConfig

ENGINES = {
    "default": CMaxConfig(),
    "by estimates": CMaxConfig(window=WindowPolicy(rate_events=0)),
}


def flip(folder: Path, sensor: str, index: int) -> Recording:
    """Flip ``index`` with ``sensor`` (written to ``folder`` the first time)."""
    path = folder / f"flip_{sensor}_{index}.h5"
    if not path.exists():
        config = SimConfig(
            duration_ms=800,
            camera=Camera(128, 128, 115.0, 115.0, 64.0, 64.0),
            trajectory=TrajectoryConfig(kind="flip"),
            sensor=sensor,
        )
        folder.mkdir(parents=True, exist_ok=True)
        write_recording(path, simulate_sequence(config, index, seed=0, split="test"))
    return read_recording(path)


def score(rec: Recording, config: CMaxConfig) -> dict:
    """One live run over ``rec``, scored against its known roll (deg, deg/s)."""
    camera = camera_from_attrs(rec.attrs, rec.events.width, rec.events.height)
    end = int(rec.gyro.t[-1])
    c0 = time.process_time()
    out = CMaxEstimator(camera, config).run(rec.events, t_end_us=end)
    cpu = (time.process_time() - c0) / (end / 1e6)
    grid = np.arange(0, end, 1000)
    k = np.searchsorted(out.t_us, grid, side="right") - 1
    held = np.where(k >= 0, out.omega[np.maximum(k, 0), 2], 0.0)
    truth = np.interp(out.t_us, rec.gyro.t, rec.gyro.omega[:, 2])
    return {
        "held": float(np.degrees(held.sum() * 1e-3)),
        "trapezoid": float(np.degrees(np.trapezoid(out.omega[:, 2], out.t_us / 1e6))),
        "mae": float(np.degrees(np.abs(out.omega[:, 2] - truth)).mean()),
        "first_ms": float(out.t_us[0] / 1e3) if len(out.t_us) else float("nan"),
        "cpu": cpu,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=4, help="Flips per sensor model.")
    parser.add_argument("--out", type=Path, default=Path("/tmp/cmax-flips"), help="Flips here.")
    args = parser.parse_args()
    print("sensor     flip  engine        held deg  trapezoid  roll MAE deg/s  first ms  CPU-s/s")
    results: dict[str, list[dict]] = {name: [] for name in ENGINES}
    for sensor in ("ideal", "davis240c"):
        for index in range(args.sequences):
            rec = flip(args.out, sensor, index)
            for name, config in ENGINES.items():
                r = score(rec, config)
                results[name].append(r)
                row = (r["held"], r["trapezoid"], r["mae"], r["first_ms"], r["cpu"])
                print(f"{sensor:10s} {index:4d}  {name:12s} {row[0]:9.1f} {row[1]:10.1f} "
                      f"{row[2]:15.1f} {row[3]:9.0f} {row[4]:8.2f}", flush=True)  # fmt: skip
    for name, rows in results.items():
        held = np.array([r["held"] for r in rows])
        print(f"{name:12s}: held {held.min():.1f}-{held.max():.1f} deg, within 5 % of 360: "
              f"{int((np.abs(held - 360) <= 18).sum())} of {len(held)}, mean |error| "
              f"{np.abs(held - 360).mean():.1f} deg; roll MAE "
              f"{np.mean([r['mae'] for r in rows]):.1f} deg/s")  # fmt: skip


if __name__ == "__main__":
    main()
