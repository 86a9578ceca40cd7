"""Does a readout that knows *where* features fire fix roll? (docs/analysis.md).

The shipped SNN-6 pools layer 5 globally (GASP) before its dense readout. This probe freezes the
five spiking conv layers and refits the linear readout by ridge regression on the same
simulated training windows, once on the global pool (256 features, the paper's readout) and once
on a coarse grid (256 x rows x columns features, the ``snn6-grid`` variant), both through the
readout's own PSP filter (τs = 8 ms), scored per axis on held-out simulated windows and on real
DAVIS240C windows with a reference angular velocity. The shipped readout (no refit) is the
reference row. If roll improves with the grid and not with the refit global readout, position
is what the readout lacked; if neither helps, the conv features themselves lack roll evidence.

    python scripts/analysis/roll_readout.py --train-data DIR --test-data DIR \
        [--real EVENTS:CALIB:GYRO ...] [--grid 2 3] [--windows 120]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from spikegyro.events.calib import resolve_calibration
from spikegyro.events.io import read_gyro, read_recording
from spikegyro.events.representations import spike_tensor
from spikegyro.models.registry import PRETRAINED_SNN6, load_checkpoint
from spikegyro.snn.functional import psp
from spikegyro.snn.layers import RegionPool
from spikegyro.stream.predict import event_mapper
from spikegyro.train.data import Window, encode_window, fixed_windows

START = 50  # steps scored, as in the paper's metrics


def grid_features(
    model: torch.nn.Module, spikes: torch.Tensor, grid: tuple[int, int]
) -> np.ndarray:
    """Layer-5 spikes pooled per grid cell and PSP-filtered like the readout: (T, 256·cells)."""
    with torch.no_grad():
        _, layers = model.forward_with_spikes(spikes[None])
        pooled = RegionPool(grid)(layers[-1])[0]  # (C·cells, T)
        filtered = psp(pooled.T.contiguous(), model.fc.srm_kernel, dim=0)
    return filtered.numpy().astype(np.float64)


def to_global(features: np.ndarray, cells: int) -> np.ndarray:
    """The global pool from equal-sized cells: the mean over each channel's cells."""
    return features.reshape(len(features), -1, cells).mean(axis=2)


def ridge(x: np.ndarray, y: np.ndarray, lam: float, prior: np.ndarray) -> np.ndarray:
    """argmin ‖xW − y‖² + lam·n·‖W − prior‖² (W: features × 3).

    Shrinking toward the shipped readout rather than toward zero: with few windows, a large
    penalty gives back the readout trained on 373k samples, a small one lets the data move it.
    """
    gram = x.T @ x + lam * len(x) * np.eye(x.shape[1])
    return prior + np.linalg.solve(gram, x.T @ (y - x @ prior))


def fit(train: list[tuple[np.ndarray, np.ndarray]], prior: np.ndarray) -> np.ndarray:
    """Ridge weights, the penalty chosen on the last fifth of the training windows."""
    cut = max(1, len(train) * 4 // 5)

    def xs(part: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        return np.concatenate([f[START:] for f, _ in part])

    def ys(part: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        return np.concatenate([g[START:] for _, g in part])

    best = min(
        (10.0**e for e in range(-7, 3)),
        key=lambda lam: np.linalg.norm(
            xs(train[cut:]) @ ridge(xs(train[:cut]), ys(train[:cut]), lam, prior) - ys(train[cut:]),
            axis=1,
        ).mean(),
    )
    print(f"  ridge penalty {best:g}")
    return ridge(xs(train), ys(train), best, prior)


def scores(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Per-axis mean absolute error and the median relative error, deg/s (steps >= START)."""
    p, g = np.degrees(pred[:, START:]).reshape(-1, 3), np.degrees(gt[:, START:]).reshape(-1, 3)
    mae = np.abs(p - g).mean(axis=0)
    norm = np.linalg.norm(g, axis=1)
    rel = np.linalg.norm(p - g, axis=1)[norm >= 1] / norm[norm >= 1]
    return {"tilt": mae[0], "pan": mae[1], "roll": mae[2], "median_rel": float(np.median(rel))}


def dataset(model, data: str, split: str, limit: int, grid) -> list[tuple[np.ndarray, np.ndarray]]:
    """(features, ω) of up to ``limit`` fixed windows, cached beside the data (``.npz``)."""
    cache = Path(data) / f"readout-features-{split}-{grid[0]}x{grid[1]}-{limit}.npz"
    if cache.exists():
        with np.load(cache) as z:
            return list(zip(z["features"], z["omega"], strict=True))
    spec = {"representation": "spikes", "sensor": [240, 180], "scale": 1.0, "window_ms": 100}
    windows = fixed_windows(data, split)[:limit]
    out = []
    for i, w in enumerate(windows):
        out.append((grid_features(model, encode_window(w, spec), grid), w.omega))
        print(f"\r{data}/{split}: {i + 1}/{len(windows)} windows", end="", flush=True)
    print()
    np.savez(cache, features=np.stack([f for f, _ in out]), omega=np.stack([g for _, g in out]))
    return out


def real_recording(spec: str, max_ms: int) -> Window:
    """A real recording ``EVENTS:CALIB:GYRO`` as a window on the model's 240x180 pinhole."""
    events, calib, gyro = spec.split(":")
    intrinsics = tuple(float(v) for v in calib.split(",")) if "," in calib else None
    calibration, _ = resolve_calibration(events, None if intrinsics else calib, intrinsics)
    ev = read_recording(events).events
    mapped = event_mapper(ev.sensor_size, {"sensor": [240, 180]}, calibration)(ev)
    t0 = int(mapped.t[0]) // 1000 * 1000
    steps = min(max_ms, int(mapped.t[-1] - t0) // 1000)
    ref = read_gyro(gyro).interpolate(t0 + 1000 * np.arange(steps + 1))
    return Window(
        events=mapped.slice_time(t0, t0 + steps * 1000),
        t_start_us=t0,
        omega=ref[1:],
        omega_start=ref[0],
        source=str(Path(events).parent.name),
    )


def real_window(model, spec: str, grid, max_ms: int) -> tuple[np.ndarray, np.ndarray, str]:
    """Features and reference ω of a real window ``EVENTS:CALIB:GYRO``; CALIB may be fx,fy,cx,cy."""
    w = real_recording(spec, max_ms)
    ev = w.events
    spikes = spike_tensor(
        ev.x, ev.y, ev.t, ev.p, height=180, width=240, t_start_us=w.t_start_us,
        num_bins=w.num_steps,
    )  # fmt: skip
    return grid_features(model, torch.from_numpy(spikes), grid), w.omega, w.source


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=str(PRETRAINED_SNN6))
    ap.add_argument("--train-data", required=True)
    ap.add_argument("--train-split", default="train")
    ap.add_argument("--test-data", required=True)
    ap.add_argument("--windows", type=int, default=120, help="at most this many per split")
    ap.add_argument("--grid", type=int, nargs=2, default=(2, 3))
    ap.add_argument("--real", nargs="*", default=[], help="EVENTS:CALIB:GYRO real windows")
    ap.add_argument("--real-ms", type=int, default=1000, help="longest real window, ms")
    args = ap.parse_args()
    torch.set_num_threads(2)
    grid, cells = tuple(args.grid), args.grid[0] * args.grid[1]
    model, _ = load_checkpoint(args.checkpoint)
    train = dataset(model, args.train_data, args.train_split, args.windows, grid)
    test = dataset(model, args.test_data, "test", args.windows, grid)
    shipped = model.fc.weight.detach().numpy().astype(np.float64).T
    readouts = {
        "shipped readout (GASP)": (lambda f: to_global(f, cells), shipped),
        "refit GASP readout": (
            lambda f: to_global(f, cells),
            fit([(to_global(f, cells), g) for f, g in train], shipped),
        ),
        f"refit {grid[0]}x{grid[1]} grid readout": (
            lambda f: f,
            fit(train, np.repeat(shipped, cells, axis=0) / cells),
        ),
    }
    reals = [real_window(model, r, grid, args.real_ms) for r in args.real]
    header = f"{'readout':28s} {'tilt':>6s} {'pan':>6s} {'roll':>6s} {'med.rel':>7s}"
    print(f"\nsimulated test windows ({len(test)}), mean abs error deg/s, steps >= {START}")
    print(header)
    for name, (view, w) in readouts.items():
        s = scores(np.stack([view(f) @ w for f, _ in test]), np.stack([g for _, g in test]))
        print(
            f"{name:28s} {s['tilt']:6.1f} {s['pan']:6.1f} {s['roll']:6.1f} {s['median_rel']:7.3f}"
        )
    for feats, ref, label in reals:
        print(
            f"\nreal {label} ({len(ref)} ms): mean over steps >= {START} (deg/s), "
            "per-step mean abs error per axis"
        )
        truth = np.degrees(ref[START:].mean(axis=0))
        print(f"{'reference':28s} " + " ".join(f"{v:6.1f}" for v in truth))
        for name, (view, w) in readouts.items():
            pred = view(feats) @ w
            mean = np.degrees(pred[START:].mean(axis=0))
            rel = np.linalg.norm(mean - truth) / max(np.linalg.norm(truth), 1e-9)
            mae = np.degrees(np.abs(pred[START:] - ref[START:]).mean(axis=0))
            print(
                f"{name:28s} "
                + " ".join(f"{v:6.1f}" for v in mean)
                + f"   rel.err of mean {rel:5.2f}   MAE "
                + " ".join(f"{v:5.1f}" for v in mae)
            )


if __name__ == "__main__":
    main()
