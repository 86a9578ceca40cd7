"""Contrast maximization on real DAVIS240C windows: accuracy and speed, one core.

    .venv/bin/python bench/cmax.py --real ../shared/real/ecd_windows [--reference-grid 15]
        [--translboxes ../shared/real/rueckauer2016_translBoxes]

Accuracy. Each ``<name>/`` folder under ``--real`` holds ``events.txt`` and ``calib.txt`` (and
optionally ``gyro_from_mocap.txt``, ``t wx wy wz``). The estimate is what ``spikegyro baseline
cmax`` gives at its defaults for the window's middle. It is compared with an independent plain
NumPy/SciPy contrast maximization over all events of the window, measured in the same run: exact
per-event undistortion, SciPy rotations, bilinear voting, ``scipy.ndimage.gaussian_filter``
(σ = 1 px), an exhaustive grid and Nelder-Mead from its best points. Agreement with it is
self-consistency, not ground truth; the motion-capture ω of a window (±20 deg/s) is printed too.
``--translboxes``: the 2 s recording with its own gyro, streamed at the defaults.

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
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from spikegyro.baselines import cmax
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
        ours = cmax.estimate_window(rec.events, calib)
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
    t_us, omega = cmax.predict_stream(rec.events, Calibration(245.0, 245.0, 120.0, 90.0))
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
from spikegyro.baselines.cmax import estimate_window
"""
COLD = """
import sys, time
from spikegyro.baselines.cmax import estimate_window
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
            cmax.estimate_window(ev, calib, init=init, grid=False)
            n += 1
    warm_cpu = (time.process_time() - c0) / n
    c0 = time.process_time()
    for ev, calib in zip(recs, calibs, strict=True):
        cmax.estimate_window(ev, calib)
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
    problem = cmax.make_problem(recs[0], calibs[0], cmax.CMaxConfig(), np.random.default_rng(0))
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", type=Path, help="Folder of real windows (<name>/events.txt).")
    parser.add_argument("--translboxes", type=Path, help="The translBoxes folder (gyro.txt).")
    parser.add_argument(
        "--reference-grid", type=int, default=15, help="Reference grid per axis (0: skip it)."
    )
    parser.add_argument("--cold-runs", type=int, default=3)
    args = parser.parse_args()
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
