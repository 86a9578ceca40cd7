"""Contrast maximization on real DAVIS240C windows: accuracy and speed, one core.

    .venv/bin/python bench/cmax.py --real ../shared/real/ecd_windows [--reference-grid 15]
        [--translboxes ../shared/real/rueckauer2016_translBoxes]
    .venv/bin/python bench/cmax.py --make-sim sim-roll
    .venv/bin/python bench/cmax.py --stream --sim sim-roll --real ../shared/real/ecd_windows \
        --translboxes ../shared/real/rueckauer2016_translBoxes

Accuracy. Each ``<name>/`` folder under ``--real`` holds ``events.txt`` and ``calib.txt`` (and
optionally ``gyro_from_mocap.txt``, ``t wx wy wz``). The estimate is what ``spikegyro baseline
cmax`` gives at its defaults for the window's middle. It is compared with an independent plain
NumPy/SciPy contrast maximization over all events of the window, measured in the same run: exact
per-event undistortion, SciPy rotations, bilinear voting, ``scipy.ndimage.gaussian_filter``
(σ = 1 px), an exhaustive grid and Nelder-Mead from its best points. Agreement with it is
self-consistency, not ground truth; the motion-capture ω of a window (±20 deg/s) is printed too.
``--translboxes``: the 2 s recording with its own gyro, streamed at the defaults.

Streaming (``--stream``): the live estimator of ``spikegyro predict --method cmax`` on whole
recordings with a gyro (translBoxes, ``--sim DIR`` simulated rolls made by ``--make-sim DIR``,
the ECD ``shapes`` window): per-axis mean absolute error against the gyro interpolated at each
estimate's time at 10, 100 and 1,000 Hz output, latency, and CPU-seconds per second of events;
then the speed table over event rates (a simulated roll played 1-8x faster: a faithful faster
rotation, so windows shorten as they would) against the previous engine (one 30,000-event window
every 10,000 events, warm-started), measured in the same run.

Speed (CPU seconds, so that other processes on a shared machine distort it less):
- cold: a new Python process estimating one window, imports and Numba cache loading included
  (its CPU time, the median of ``--cold-runs``, and that of a process that only imports);
- warm: a running process over consecutive windows, each warm-started from the previous one's
  estimate (the dev windows, each started from a neighbour's estimate off by about 20 deg/s);
- the same run times one evaluation of the plain NumPy objective and of ours, and prints the
  ratios.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.live import CMaxEstimator
from spikegyro.cmax.problem import camera_from_attrs, make_problem
from spikegyro.cmax.search import estimate_window
from spikegyro.cmax.series import predict_stream
from spikegyro.events.calib import load_calibration
from spikegyro.events.io import read_recording

WIDTH, HEIGHT = 240, 180


def plain_contrast(rays: np.ndarray, dt: np.ndarray, omega: np.ndarray, k: np.ndarray) -> float:
    """Variance of the σ = 1 px blurred IWE, all in NumPy/SciPy (the independent reference)."""
    r = Rotation.from_rotvec(-np.outer(dt, omega)).apply(rays)
    u = k[0] * r[:, 0] / r[:, 2] + k[2]
    v = k[1] * r[:, 1] / r[:, 2] + k[3]
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - u0, v - v0
    image = np.zeros(WIDTH * HEIGHT)
    for du, dv, w in (
        (0, 0, (1 - fu) * (1 - fv)),
        (1, 0, fu * (1 - fv)),
        (0, 1, (1 - fu) * fv),
        (1, 1, fu * fv),
    ):
        x, y = u0 + du, v0 + dv
        ok = (x >= 0) & (x < WIDTH) & (y >= 0) & (y < HEIGHT)
        image += np.bincount(y[ok] * WIDTH + x[ok], w[ok], minlength=WIDTH * HEIGHT)
    return float(gaussian_filter(image.reshape(HEIGHT, WIDTH), 1.0).var())


def plain_rays(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays (N, 3) undistorted per event by fixed-point iteration, t_ref - t (s), intrinsics."""
    ev = np.loadtxt(folder / "events.txt")
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = np.loadtxt(folder / "calib.txt")
    xd, yd = (ev[:, 1] - cx) / fx, (ev[:, 2] - cy) / fy
    x, y = xd.copy(), yd.copy()
    for _ in range(50):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        x = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / radial
        y = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / radial
    t = ev[:, 0]
    return (
        np.column_stack([x, y, np.ones_like(x)]),
        0.5 * (t[0] + t[-1]) - t,
        np.array([fx, fy, cx, cy]),
    )


def plain_cmax(folder: Path, grid_points: int) -> np.ndarray:
    """The reference ω (rad/s): exhaustive grid on 8,000 events, Nelder-Mead on all of them."""
    rays, dt, k = plain_rays(folder)
    px = k[0] * np.abs(dt).max()
    reach = min(np.radians(1000.0), 40.0 / px)
    axis = np.linspace(-reach, reach, grid_points)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    sub = np.random.default_rng(0).choice(len(dt), min(8000, len(dt)), replace=False)
    scores = [plain_contrast(rays[sub], dt[sub], g, k) for g in grid]
    best, best_score = np.zeros(3), -np.inf
    for start in grid[np.argsort(scores)[::-1][:4]]:
        simplex = start + np.vstack([np.zeros(3), np.eye(3) * 2.0 / px])
        res = minimize(
            lambda w: -plain_contrast(rays, dt, w, k),
            start,
            method="Nelder-Mead",
            options={"xatol": 1e-4, "fatol": 1e-12, "initial_simplex": simplex},
        )
        if -res.fun > best_score:
            best, best_score = res.x, -res.fun
    return best


def accuracy(folders: list[Path], grid_points: int) -> list[np.ndarray]:
    print(
        "window         events  span ms   ours (deg/s)              "
        "plain NumPy CMax          |diff|  mocap |err|"
    )
    diffs, estimates = [], []
    for folder in folders:
        rec = read_recording(folder / "events.txt")
        calib = load_calibration(folder / "calib.txt")
        ours = estimate_window(rec.events, calib)
        estimates.append(ours)
        ref = plain_cmax(folder, grid_points) if grid_points > 0 else np.full(3, np.nan)
        diff = np.degrees(np.linalg.norm(ours - ref))
        diffs.append(diff)
        line = (
            f"{folder.name:14s} {len(rec.events):7,d} {rec.events.duration_us / 1000:7.1f}   "
            f"{np.array2string(np.degrees(ours), precision=1):25s} "
            f"{np.array2string(np.degrees(ref), precision=1):25s} {diff:5.1f}"
        )
        mocap = folder / "gyro_from_mocap.txt"
        if mocap.is_file():
            g = np.loadtxt(mocap)
            mid = 0.5 * (rec.events.t[0] + rec.events.t[-1]) * 1e-6
            truth = np.array([np.interp(mid, g[:, 0], g[:, i]) for i in (1, 2, 3)])
            line += f"  {np.degrees(np.linalg.norm(ours - truth)):5.1f}"
        print(line, flush=True)
    print(f"mean |ours - plain NumPy CMax|: {np.mean(diffs):.1f} deg/s over {len(diffs)} windows")
    return estimates


def translboxes(folder: Path) -> None:
    from spikegyro.events.calib import Calibration

    rec = read_recording(folder / "events.txt")
    gyro = np.loadtxt(folder / "gyro.txt")
    t_us, omega = predict_stream(rec.events, Calibration(245.0, 245.0, 120.0, 90.0))
    truth = np.column_stack([np.interp(t_us * 1e-6, gyro[:, 0], gyro[:, i]) for i in (1, 2, 3)])
    err = np.degrees(np.linalg.norm(omega - truth, axis=1))
    bias = np.radians([3.5, -1.0, 0.0])  # the gyro's bias (README): not removed in gyro.txt
    err_unbiased = np.degrees(np.linalg.norm(omega - (truth - bias), axis=1))
    print(
        f"translBoxes: {len(t_us)} windows, mean error vs gyro {err.mean():.1f} deg/s "
        f"({err_unbiased.mean():.1f} with the README's bias removed); mean |gyro| "
        f"{np.degrees(np.linalg.norm(truth, axis=1)).mean():.1f} deg/s"
    )


COLD_IMPORTS = """
from spikegyro.cmax.search import estimate_window
"""
COLD = """
import sys, time
from spikegyro.cmax.search import estimate_window
from spikegyro.events.calib import load_calibration
from spikegyro.events.io import read_recording
rec = read_recording(sys.argv[1] + '/events.txt')
estimate_window(rec.events, load_calibration(sys.argv[1] + '/calib.txt'))
"""


def speed(folders: list[Path], estimates: list[np.ndarray], cold_runs: int) -> None:
    cold, cold_cpu, import_cpu = [], [], []
    for k in range(cold_runs):
        for script, sink in ((COLD, cold_cpu), (COLD_IMPORTS, import_cpu)):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            w0 = time.perf_counter()
            folder = str(folders[k % len(folders)])
            subprocess.run([sys.executable, "-c", script, folder], check=True)
            wall = time.perf_counter() - w0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            sink.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
            if script is COLD:
                cold.append(wall)
    print(
        f"cold: {1 / statistics.median(cold_cpu):.2f} estimates per CPU-second (a new process "
        f"per window, median of {cold_runs}: {statistics.median(cold_cpu):.2f} CPU-s, of which "
        f"the imports {statistics.median(import_cpu):.2f}; {statistics.median(cold):.2f} s wall)"
    )
    recs = [read_recording(f / "events.txt").events for f in folders]
    calibs = [load_calibration(f / "calib.txt") for f in folders]
    rng = np.random.default_rng(0)
    n, c0 = 0, time.process_time()
    for _ in range(5):
        for ev, calib, est in zip(recs, calibs, estimates, strict=True):
            init = est + np.radians(rng.normal(0.0, 20.0, 3))
            estimate_window(ev, calib, init=init, grid=False)
            n += 1
    warm_cpu = (time.process_time() - c0) / n
    c0 = time.process_time()
    for ev, calib in zip(recs, calibs, strict=True):
        estimate_window(ev, calib)
    search_cpu = (time.process_time() - c0) / len(recs)
    sizes = [len(ev) for ev in recs]
    print(
        f"warm: {1 / warm_cpu:.1f} estimates per CPU-second ({n} windows of "
        f"{min(sizes):,}-{max(sizes):,} events, all used; warm start off by ~20 deg/s)"
    )
    print(f"full search in a running process: {1 / search_cpu:.1f} estimates per CPU-second")
    # One objective evaluation: the plain NumPy reference against ours, same events.
    rays, dt, k = plain_rays(folders[0])
    c0 = time.process_time()
    for _ in range(10):
        plain_contrast(rays, dt, estimates[0], k)
    plain_eval = (time.process_time() - c0) / 10
    problem = make_problem(recs[0], calibs[0], CMaxConfig(), np.random.default_rng(0))
    c0 = time.process_time()
    for _ in range(50):
        problem.contrast(estimates[0], 1, 1.0, gradient=True)
    ours_eval = (time.process_time() - c0) / 50
    print(
        f"one objective evaluation on {len(dt):,} events: plain NumPy {plain_eval * 1e3:.1f} ms, "
        f"ours with its gradient {ours_eval * 1e3:.2f} ms ({plain_eval / ours_eval:.0f}x); a warm "
        f"estimate costs {warm_cpu / plain_eval:.1f} plain NumPy evaluations, a full search "
        f"{search_cpu / plain_eval:.1f}"
    )
    print(f"load average: {os.getloadavg()[0]:.1f} (absolute timings are distorted by other load)")


def simulate_roll(seconds: float, seed: int):
    """A DAVIS240C-like recording (the ``davis240c`` sensor preset: noise, hot pixels, lens
    mapped onto the pinhole) of a camera rolling at 20-40 deg/s with ±2 deg/s of tilt and pan."""
    from dataclasses import replace

    from spikegyro.events.core import Recording
    from spikegyro.sim import Trajectory, simulate
    from spikegyro.sim.dataset import SimConfig, _sensor_recording, _sensor_scene, _splits
    from spikegyro.sim.sensor import sensor_preset
    from spikegyro.sim.trajectory import random_rotation

    rng = np.random.default_rng(seed)
    config = SimConfig(sensor="davis240c")
    preset = sensor_preset("davis240c")
    sensor = preset.draw(rng)
    kind, pano = _sensor_scene(preset, preset.scenes, rng, _splits(config)["test"], 1024, "roll")
    t = np.linspace(0, seconds, 200)
    phase = rng.uniform(0, 2 * np.pi, 3)
    roll = 30 + 10 * np.sin(2 * np.pi * t / 1.7 + phase[0])
    small = 2.0 * np.sin(2 * np.pi * t / 1.1 + phase[1:, None]).T
    omega = np.radians(np.column_stack([small[:, 0], small[:, 1], roll]))
    traj = Trajectory(t, omega, r0=random_rotation(rng), duration_s=seconds)
    ev = replace(config.events, contrast_on=sensor.contrast_on, contrast_off=sensor.contrast_off)
    rec = _sensor_recording(simulate(pano, traj, config.camera, ev, rng, seconds, sensor=sensor),
                            config, preset, sensor)  # fmt: skip
    return Recording(rec.events, rec.gyro, {**rec.attrs, "scene_kind": kind})


def stream_once(events, camera, gyro, rate_hz: float, bias=None) -> dict:
    """One streaming run: per-axis MAE (deg/s) from 50 ms on, latency, CPU-s per s of events."""

    est = CMaxEstimator(camera, CMaxConfig(rate_hz=rate_hz))
    c0 = time.process_time()
    out = est.run(events)
    cpu = time.process_time() - c0
    seconds = (int(events.t[-1]) - int(events.t[0])) / 1e6
    row = {"estimates": len(out), "cpu_per_s": cpu / seconds, "rate": len(out) / seconds,
           "latency_ms": float(np.median(out.delay_us)) / 1000 if len(out) else np.nan}  # fmt: skip
    if gyro is not None and len(out):
        ref = gyro.interpolate(out.t_us)
        if bias is not None:
            ref = ref - bias
        ok = (out.t_us > est.t0_us + 50_000) & (out.t_us <= gyro.t[-1]) & (out.t_us >= gyro.t[0])
        row["mae"] = np.degrees(np.abs(out.omega[ok] - ref[ok])).mean(axis=0)
        row["scored"] = int(ok.sum())
    return row


def stream_accuracy(recordings: list[tuple[str, object, object, object, object]]) -> None:
    print("recording                 rate Hz  estimates  tilt   pan  roll (MAE deg/s)  "
          "latency ms  CPU-s per s")  # fmt: skip
    for name, events, camera, gyro, bias in recordings:
        for rate in (10.0, 100.0, 1000.0):
            r = stream_once(events, camera, gyro, rate, bias)
            mae = r.get("mae", np.full(3, np.nan))
            print(f"{name:25s} {rate:7.0f} {r['estimates']:10d} {mae[0]:5.2f} {mae[1]:5.2f} "
                  f"{mae[2]:5.2f}  {r['latency_ms']:17.1f} {r['cpu_per_s']:12.3f}",
                  flush=True)  # fmt: skip


def previous_engine_cpu_per_s(events, camera) -> float:
    """CPU-s per s of events of the previous `baseline cmax`: a 30,000-event window every
    10,000 events, each warm-started from the last and refined on all its events."""
    c0 = time.process_time()
    previous = None
    for i0 in range(0, max(len(events) - 30_000, 0) + 1, 10_000):
        window = events[i0 : i0 + 30_000]
        previous = estimate_window(window, camera, init=previous, grid=previous is None)
    return (time.process_time() - c0) / ((int(events.t[-1]) - int(events.t[0])) / 1e6)


def speed_table(events, camera) -> None:
    """CPU-s per s of events at 100 Hz against the event rate (the recording played faster)."""
    print("speed-up  M events/s  ours CPU-s/s (100 Hz)  real-time factor  previous CPU-s/s")
    below = None
    for factor in (1, 2, 4, 8):
        fast = events.shift_time(-int(events.t[0]))
        fast = replace(fast, t=fast.t // factor)
        seconds = int(fast.t[-1]) / 1e6
        ours = stream_once(fast, camera, None, 100.0)["cpu_per_s"]
        prev = previous_engine_cpu_per_s(fast, camera) if factor <= 2 else float("nan")
        rate = len(fast) / seconds / 1e6
        print(f"{factor:8d} {rate:11.2f} {ours:22.3f} {1 / ours:17.2f} {prev:17.3f}", flush=True)
        if ours > 1 and below is None:
            below = rate
    where = "> the rates tried" if below is None else f"{below:.2f} M events/s"
    print(f"falls below real time at: {where}")


def stream(args: argparse.Namespace) -> None:
    from spikegyro.events.calib import Calibration
    from spikegyro.events.io import read_gyro

    recordings = []
    if args.translboxes:
        t = args.translboxes
        camera = Calibration(245.0, 245.0, 120.0, 90.0)
        ev, gyro = read_recording(t / "events.txt").events, read_gyro(t / "gyro.txt")
        recordings.append(("translBoxes", ev, camera, gyro, None))
        bias = np.radians([3.5, -1.0, 0.0])  # the README's gyro bias (camera frame)
        recordings.append(("translBoxes, bias removed", ev, camera, gyro, bias))
    if args.real and (args.real / "shapes_rotation").is_dir():
        f = args.real / "shapes_rotation"
        gyro = read_gyro(f / "gyro_from_mocap.txt")
        recordings.append(("ECD shapes (mocap)", read_recording(f / "events.txt").events,
                           load_calibration(f / "calib.txt"), gyro, None))  # fmt: skip
    sims = sorted(args.sim.glob("*.h5")) if args.sim else []
    for path in sims:
        rec = read_recording(path)
        camera = camera_from_attrs(rec.attrs, *rec.events.sensor_size)
        rate = len(rec.events) / (rec.events.duration_us / 1e6) / 1e6
        recordings.append((f"sim {path.stem} {rate:.2f}M/s", rec.events, camera, rec.gyro, None))
    stream_accuracy(recordings)
    if sims:
        rec = read_recording(sims[0])
        speed_table(rec.events, camera_from_attrs(rec.attrs, *rec.events.sensor_size))
    print(f"load average: {os.getloadavg()[0]:.1f} (CPU seconds; wall time suffers more)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", type=Path, help="Folder of real windows (<name>/events.txt).")
    parser.add_argument("--translboxes", type=Path, help="The translBoxes folder (gyro.txt).")
    parser.add_argument(
        "--reference-grid", type=int, default=15, help="Reference grid per axis (0: skip it)."
    )
    parser.add_argument("--cold-runs", type=int, default=3)
    parser.add_argument("--stream", action="store_true", help="The live estimator's tables.")
    parser.add_argument("--sim", type=Path, help="Folder of simulated roll recordings (*.h5).")
    parser.add_argument("--make-sim", type=Path, help="Write 3 simulated 3.2 s rolls here.")
    args = parser.parse_args()
    if args.make_sim:
        from spikegyro.events.io import write_recording

        args.make_sim.mkdir(parents=True, exist_ok=True)
        for seed in (1, 2, 3):
            write_recording(args.make_sim / f"roll{seed}.h5", simulate_roll(3.2, seed))
        return
    if args.stream:
        stream(args)
        return
    folders = sorted(p.parent for p in args.real.glob("*/events.txt")) if args.real else []
    if not folders:
        print("no real windows (pass --real DIR): accuracy and speed skipped")
        return
    estimates = accuracy(folders, args.reference_grid)
    if args.translboxes and (args.translboxes / "gyro.txt").is_file():
        translboxes(args.translboxes)
    speed(folders, estimates, args.cold_runs)


if __name__ == "__main__":
    main()
