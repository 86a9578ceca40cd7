"""How often the live CMax engine flags estimates, on still cameras and on rotating ones.

    python bench/cmax_flag.py [--real ../shared/real] [--sim-dir /tmp/cmax-flag] [--rounds 1]
        [--only NAME ...]

Streams each recording through :class:`~spikegyro.cmax.live.CMaxEstimator` at its defaults
(100 Hz, the one-rotation test on) and prints, per recording, the estimates' count and the
share of them that carry any ``ill_posed`` bit, bit 4 ("one rotation does not explain the
events"), and any bit or |ω| within 3 deg/s of zero. A still camera should be flagged (or read
about zero) nearly always; a rotating one should rarely carry bit 4. Beside them, the CPU time
of the same run with ``CMaxConfig(one_rotation=None)``, run alternately in the same process
(``--rounds`` times each; the ratio of the medians).

Recordings: real ones under ``--real`` where present (still: the DVXplorer with its IMU, the
DVS128 hand wave, the eDVS128 bar sweeps, all three with the default pinhole, f = 200 px per
240 px of sensor width, since none was calibrated; rotating: translBoxes and rot_bars at
fx = fy = 245 px, c = (120, 90), and the Event Camera Dataset windows with their calib.txt);
simulated DAVIS240C recordings written once to ``--sim-dir`` (a slow hand-held-like rotation,
``spikegyro simulate --slow-share 1``'s trajectory, 2 s; the demo's trajectory, 4 s; two
sequences at the paper's speeds, 0.5 s each); and the composed recordings of the tests
(``tests/scene_helpers.py``: objects moving before a still camera, rotations), 1 s each.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import statistics
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.problem import camera_from_attrs, default_camera
from spikegyro.events.calib import Calibration, load_calibration
from spikegyro.events.io import read_recording, write_recording
from spikegyro.sim.dataset import SimConfig, simulate_sequence
from spikegyro.sim.trajectory import TrajectoryConfig
from spikegyro.stream.estimator import ILL_NOT_ONE_ROTATION

# The composed recordings are the tests' own (one definition of each scene).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from scene_helpers import scenes

DAVIS = (245.0, 245.0, 120.0, 90.0)  # translBoxes' README: rot_bars is the same camera
SIMULATED = {
    "sim slow hand-held (2 s)": (
        SimConfig(duration_ms=2000, trajectory=TrajectoryConfig(slow_share=1.0)), 11),
    "sim demo trajectory (4 s)": (
        SimConfig(duration_ms=4000, trajectory=TrajectoryConfig(accel_std_deg=300.0)), 2027),
    "sim paper speeds, seed 1 (0.5 s)": (SimConfig(duration_ms=500), 1),
    "sim paper speeds, seed 2 (0.5 s)": (SimConfig(duration_ms=500), 2),
}  # fmt: skip


def real(root: Path) -> Iterator[tuple[str, bool, object, object]]:
    """(name, still camera?, events, camera) of the real recordings present under ``root``."""
    still = {
        "DVXplorer, still (IMU)": (root / "formats/dvxplorer_static_imu.aedat4", None),
        "DVS128 hand wave, still": (root / "static/dvs128_hand_wave/events.txt", (128, 128)),
        "eDVS128 bar sweeps, still": (root / "static/edvs128_bar_sweeps/events.txt", (128, 128)),
    }
    for name, (path, sensor) in still.items():
        if path.exists():
            events = read_recording(path, sensor=sensor).events
            yield name, True, events, default_camera(events.width, events.height)
    rotating = {
        "translBoxes (gyro)": root / "rueckauer2016_translBoxes/events.txt",
        "rot_bars": root / "unlabeled/davis240_rotbars/events.txt",
    }
    for name, path in rotating.items():
        if path.exists():
            yield name, False, read_recording(path).events, Calibration(*DAVIS)
    for folder in sorted((root / "ecd_windows").glob("*_rotation")):
        calib = load_calibration(folder / "calib.txt")
        yield f"ECD {folder.name}", False, read_recording(folder).events, calib


def simulated(folder: Path) -> Iterator[tuple[str, bool, object, object]]:
    """The simulated rotations (written to ``folder`` the first time)."""
    for k, (name, (sim, seed)) in enumerate(SIMULATED.items()):
        path = folder / f"rotation-{k}-{seed}.h5"
        if not path.exists():
            folder.mkdir(parents=True, exist_ok=True)
            write_recording(path, simulate_sequence(sim, 0, seed, split="test"))
        rec = read_recording(path)
        camera = camera_from_attrs(rec.attrs, rec.events.width, rec.events.height)
        yield name, False, rec.events, camera


def composed() -> Iterator[tuple[str, bool, object, object]]:
    """The tests' composed recordings, 1 s each (240 x 180, f = 200 px)."""
    camera = default_camera(240, 180)
    for name, (events, still) in scenes(1.0, seed=0).items():
        yield f"composed {name}", still, events, camera


def run(events, camera, config: CMaxConfig) -> tuple[object, float]:
    """The live estimates over ``events`` and the process CPU seconds they took."""
    start = time.process_time()
    found = CMaxEstimator(camera, config).run(events)
    return found, time.process_time() - start


def measure(events, camera, rounds: int) -> dict:
    """Flag shares of the default engine, and its CPU time over that without the test."""
    config = CMaxConfig()
    bare = replace(config, one_rotation=None)
    spent: dict[str, list[float]] = {"test": [], "none": []}
    for _ in range(rounds):
        found, cpu = run(events, camera, config)
        spent["test"].append(cpu)
        spent["none"].append(run(events, camera, bare)[1])
    flags = found.ill_posed
    near_zero = np.degrees(np.linalg.norm(found.omega, axis=1)) <= 3.0
    n = max(len(found), 1)
    return {
        "n": len(found),
        "any": float((flags > 0).sum()) / n,
        "bit4": float(((flags & ILL_NOT_ONE_ROTATION) > 0).sum()) / n,
        "or_zero": float(((flags > 0) | near_zero).sum()) / n,
        "ratio": statistics.median(spent["test"]) / max(statistics.median(spent["none"]), 1e-9),
        "cpu": statistics.median(spent["test"]),
        "cpu_none": statistics.median(spent["none"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", type=Path, help="The shared real recordings' folder.")
    parser.add_argument("--sim-dir", type=Path, help="Folder for the simulated recordings.")
    parser.add_argument("--rounds", type=int, default=1, help="Runs of each configuration.")
    parser.add_argument("--only", nargs="+", default=[], help="Recordings whose name has these.")
    args = parser.parse_args()
    sources = [composed()]
    if args.real is not None:
        sources.insert(0, real(args.real))
    if args.sim_dir is not None:
        sources.insert(1, simulated(args.sim_dir))
    print("camera    recording                           estimates  any bit  bit 4  "
          "any or |w|<3  CPU-s (test / none)  ratio")  # fmt: skip
    total = {"test": 0.0, "none": 0.0}
    for source in sources:
        for name, still, events, camera in source:
            if args.only and not any(part in name for part in args.only):
                continue
            r = measure(events, camera, args.rounds)
            total["test"] += r["cpu"]
            total["none"] += r["cpu_none"]
            kind = "still" if still else "rotating"
            print(f"{kind:9s} {name:36s} {r['n']:9d}  {r['any']:6.1%}  {r['bit4']:6.1%}  "
                  f"{r['or_zero']:12.1%}  {r['cpu']:8.2f} / {r['cpu_none']:6.2f}  "
                  f"{r['ratio']:5.2f}", flush=True)  # fmt: skip
    print(f"all recordings: CPU {total['test']:.1f} s with the test, {total['none']:.1f} s "
          f"without: {total['test'] / max(total['none'], 1e-9):.2f}x")  # fmt: skip


if __name__ == "__main__":
    main()
