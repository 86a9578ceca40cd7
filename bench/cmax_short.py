"""Offline CMax on short recordings against one estimate over the whole span, one core.

    .venv/bin/python bench/cmax_short.py [--seeds 3] [--ecd ../shared/real/ecd_windows]

Simulated: 100 ms sequences (``simulate_sequence``, test split, seeds 0 .. N-1) on the ideal
sensor and on the ``davis240c`` preset, under the default random rotation (acceleration
150 deg/s² per axis: nearly steady over 100 ms) and one that changes fast (3,000 deg/s²), cut to
their first 10, 30 and 100 ms. Per window, three estimators, each scored by the mean Euclidean
error (deg/s) against the true ω at the offline estimates' own times:

- ``window``: the offline engine with its own windows only (``OfflineConfig(whole_max_ms=0)``,
  the engine before it compared with the whole span);
- ``offline``: the offline engine at its defaults (``predict --method cmax --offline``);
- ``whole``: one estimate from all events (``spikegyro baseline cmax --whole``), held at those
  times.

``--ecd``: the same on the four real ECD windows (``calib.txt`` each); where a window has
``gyro_from_mocap.txt``, errors against it, else the offline estimates' distance from the whole
span's.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
from pathlib import Path

import numpy as np

from spikegyro.cmax.offline import OfflineConfig, estimate_offline
from spikegyro.cmax.problem import camera_from_attrs
from spikegyro.cmax.search import estimate_whole
from spikegyro.events.calib import load_calibration
from spikegyro.events.io import read_recording
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.sim.trajectory import TrajectoryConfig

SPANS_MS = (10, 30, 100)
ACCELERATIONS = (150.0, 3000.0)
WINDOW_ONLY = OfflineConfig(whole_max_ms=0.0)


def sampled(t_us: np.ndarray, omega: np.ndarray):
    """``reference(t) -> (n, 3)`` rad/s: ``omega`` (K, 3) at ``t_us`` (K,) interpolated."""
    return lambda t: np.column_stack([np.interp(t, t_us, w) for w in omega.T])


def errors(events, camera, reference) -> tuple[float, float, float, int]:
    """Mean Euclidean errors (deg/s) of the window-only engine, the default one and the whole
    span's estimate against ``reference(t_us) -> (n, 3)`` rad/s, and the estimates' count."""
    window = estimate_offline(events, camera, WINDOW_ONLY)
    offline = estimate_offline(events, camera)
    whole = estimate_whole(events, camera)
    truth = reference(offline.t_us)

    def mean(omega: np.ndarray) -> float:
        return float(np.degrees(np.linalg.norm(omega - truth, axis=1)).mean())

    return mean(window.omega), mean(offline.omega), mean(whole), len(offline)


def simulated(seeds: int) -> list[tuple[str, float, float, float]]:
    """Rows (name, window, offline, whole) of the simulated windows."""
    rows = []
    for sensor in ("ideal", "davis240c"):
        for accel in ACCELERATIONS:
            motion = TrajectoryConfig(accel_std_deg=accel)
            for seed in range(seeds):
                rec = simulate_sequence(
                    SimConfig(duration_ms=100, sensor=sensor, trajectory=motion), 0, seed, "test"
                )
                camera = camera_from_attrs(rec.attrs, *rec.events.sensor_size)
                reference = sampled(rec.gyro.t, rec.gyro.omega)
                for span in SPANS_MS:
                    events = rec.events.slice_time(0, span * 1000)
                    *err, n = errors(events, camera, reference)
                    name = f"{sensor} {accel:g} deg/s² seed {seed} {span} ms ({n} est.)"
                    rows.append((name, *err))
                    print(f"{name:48s} window {err[0]:7.2f} offline {err[1]:7.2f} "
                          f"whole {err[2]:7.2f}", flush=True)  # fmt: skip
    return rows


def ecd(folder: Path) -> None:
    """The four ECD windows: errors against motion capture where there is one, else the
    offline estimates' distance from the whole span's estimate."""
    for path in sorted(p for p in folder.iterdir() if (p / "events.txt").exists()):
        events = read_recording(path / "events.txt").events
        camera = load_calibration(path / "calib.txt")
        mocap = path / "gyro_from_mocap.txt"
        if mocap.exists():
            table = np.loadtxt(mocap)
            reference = sampled(np.rint(table[:, 0] * 1e6), table[:, 1:])
            window, offline, whole, n = errors(events, camera, reference)
            print(f"{path.name}: {n} estimates, error against motion capture: window "
                  f"{window:.1f}, offline {offline:.1f}, whole {whole:.1f} deg/s")  # fmt: skip
            continue
        whole = estimate_whole(events, camera)
        for name, config in (("window", WINDOW_ONLY), ("offline", OfflineConfig())):
            est = estimate_offline(events, camera, config)
            gap = np.degrees(np.linalg.norm(est.omega - whole, axis=1)).mean()
            print(f"{path.name}: {name} {len(est)} estimate(s), {gap:.1f} deg/s from the whole "
                  f"span's {np.degrees(whole).round(1)}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=3, help="simulated sequences per motion")
    parser.add_argument("--ecd", type=Path, default=None, help="folder of the ECD windows")
    args = parser.parse_args()
    rows = simulated(args.seeds)
    err = np.array([r[1:] for r in rows])
    worse = (err[:, :2] > err[:, 2:3] + 1e-9).sum(axis=0)
    print(f"mean over {len(rows)} windows: window {err[:, 0].mean():.2f}, offline "
          f"{err[:, 1].mean():.2f}, whole {err[:, 2].mean():.2f} deg/s; worse than whole: "
          f"window {worse[0]}, offline {worse[1]}")  # fmt: skip
    if args.ecd is not None:
        ecd(args.ecd)


if __name__ == "__main__":
    main()
