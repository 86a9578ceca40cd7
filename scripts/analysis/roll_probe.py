"""Which input statistic does SNN-6's roll estimate hang on? (docs/analysis.md).

Runs a checkpoint on simulated test windows, each time changing one statistic in which the real
sparse recordings differ from the simulator's, and prints per-axis mean absolute errors:

- ``all``: the windows as simulated (the reference row);
- ``thinned K``: a random share K of the events kept (density alone: the real ``shapes`` window
  has about a third of a median simulated window's events);
- ``centre F``: only events inside a centred box of F times each side (spatial extent alone:
  a few shapes in the middle of the view, no events near the image border);
- ``periphery F``: only events outside that box.

If roll degrades with ``centre`` far more than tilt and pan do, and not with ``thinned``, the
network reads roll from where events fall across the whole view (flow that turns with position,
or the conv layers' zero padding at the border), and a readout that keeps position should help.

Real windows with a reference (``EVENTS:CALIB:GYRO``; CALIB may be ``fx,fy,cx,cy``) are run as
recorded and through the symmetries the network was trained with (left-right and up-down mirror,
time reversal), each prediction mapped back to the original frame. An equivariant network
gives the same mean each time; the spread says how much of an estimate is bias, not evidence.

    python scripts/analysis/roll_probe.py --data DIR [--checkpoint PT] [--windows 100] \
        [--real SPEC ...]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
import torch
from roll_readout import START, real_recording, scores

from spikegyro.models.registry import PRETRAINED_SNN6, load_checkpoint
from spikegyro.train.augment import (
    HORIZONTAL_MIRROR,
    VERTICAL_MIRROR,
    centre_mask,
    flip_horizontal,
    flip_vertical,
    keep_centre,
    mirror_omega,
    reverse_time,
    thin,
)
from spikegyro.train.data import Window, encode_window, fixed_windows

SPEC = {"representation": "spikes", "sensor": [240, 180], "scale": 1.0, "window_ms": 100}
Transform = Callable[[Window, np.random.Generator], Window]


def thinned(keep: float) -> Transform:
    return lambda w, rng: thin(w, rng.random(len(w.events)) < keep)


def centre(fraction: float) -> Transform:
    return lambda w, rng: keep_centre(w, fraction)


def periphery(fraction: float) -> Transform:
    return lambda w, rng: thin(w, ~centre_mask(w.events, fraction))


def encoded(window: Window) -> torch.Tensor:
    """The network's input for a window, (1, 2, H, W, T)."""
    return encode_window(window, {**SPEC, "window_ms": window.num_steps})[None]


def predict(model: torch.nn.Module, window: Window) -> np.ndarray:
    """(T, 3) angular velocity, rad/s."""
    with torch.no_grad():
        return model(encoded(window))[0].T.numpy().astype(np.float64)


def firing(model: torch.nn.Module, window: Window) -> np.ndarray:
    """Per layer, % of its neurons that fire per step, over steps >= START."""
    with torch.no_grad():
        _, spikes = model.forward_with_spikes(encoded(window))
    return np.array([100.0 * float(s[..., START:].mean()) for s in spikes])


def activity(model, window: Window, simulated_windows: list[Window]) -> None:
    """Does the real window drive the network like simulated windows of its event rate?"""
    rate = len(window.events) / window.num_steps
    alike = [w for w in simulated_windows if 2 / 3 < len(w.events) / w.num_steps / rate < 1.5]
    print(f"firing, % of neurons per step (layers 1..5), real at {rate:.0f} events/ms: "
          + " / ".join(f"{v:.2f}" for v in firing(model, window)))  # fmt: skip
    if alike:
        sim = np.median([firing(model, w) for w in alike], axis=0)
        print(f"  simulated test windows at {rate * 2 / 3:.0f}-{rate * 1.5:.0f} events/ms "
              f"(median of {len(alike)}): " + " / ".join(f"{v:.2f}" for v in sim))  # fmt: skip


def simulated(model, windows: list[Window], keep: float, fraction: float, seed: int) -> None:
    conditions: dict[str, Transform] = {
        "all": lambda w, rng: w,
        f"thinned {keep:g}": thinned(keep),
        f"centre {fraction:g}": centre(fraction),
        f"periphery {fraction:g}": periphery(fraction),
    }
    print(f"\nsimulated windows ({len(windows)}), mean abs error deg/s over steps >= {START}")
    print(f"{'events':16s} {'share':>6s} {'tilt':>6s} {'pan':>6s} {'roll':>6s} {'med.rel':>7s}")
    for name, transform in conditions.items():
        rng = np.random.default_rng(seed)
        preds, truths, share = [], [], []
        for i, w in enumerate(windows):
            changed = transform(w, rng)
            share.append(len(changed.events) / max(len(w.events), 1))
            preds.append(predict(model, changed))
            truths.append(w.omega)
            print(f"\r{name}: {i + 1}/{len(windows)}", end="", flush=True)
        s = scores(np.stack(preds), np.stack(truths))
        print(
            f"\r{name:16s} {np.mean(share):6.2f} {s['tilt']:6.1f} {s['pan']:6.1f} "
            f"{s['roll']:6.1f} {s['median_rel']:7.3f}"
        )


def real(model, window: Window) -> None:
    """Mean estimate from step START on, as recorded and through each trained symmetry."""
    h, v = HORIZONTAL_MIRROR, VERTICAL_MIRROR
    turned = flip_vertical(flip_horizontal(window))
    views = {
        "as recorded": (window, lambda p: p),
        "mirrored left-right": (flip_horizontal(window), lambda p: mirror_omega(p, h)),
        "mirrored up-down": (flip_vertical(window), lambda p: mirror_omega(p, v)),
        "rotated 180 deg": (turned, lambda p: mirror_omega(p, h @ v)),
        "time reversed": (reverse_time(window), lambda p: -p[::-1]),
    }
    truth = np.degrees(window.omega[START:].mean(axis=0))
    print(f"\nreal {window.source} ({window.num_steps} ms), mean over steps >= {START}, deg/s")
    print(f"{'view':22s} {'tilt':>7s} {'pan':>7s} {'roll':>7s}  rel.err of mean")
    print(f"{'reference':22s} " + " ".join(f"{v:7.1f}" for v in truth))
    means = []
    for name, (view, back) in views.items():
        pred = back(predict(model, view))
        if name == "time reversed":  # bins map k <-> T-1-k, label shifted by one step
            pred = np.concatenate([pred[1:], pred[-1:]])
        mean = np.degrees(pred[START:].mean(axis=0))
        means.append(mean)
        rel = np.linalg.norm(mean - truth) / max(np.linalg.norm(truth), 1e-9)
        print(f"{name:22s} " + " ".join(f"{v:7.1f}" for v in mean) + f"  {rel:5.2f}")
    spread = np.std(means, axis=0)
    print(f"{'spread (std)':22s} " + " ".join(f"{v:7.1f}" for v in spread))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=str(PRETRAINED_SNN6))
    ap.add_argument("--data", help="dataset whose test split is probed")
    ap.add_argument("--windows", type=int, default=100, help="at most this many test windows")
    ap.add_argument("--keep", type=float, default=0.3, help="share kept by 'thinned'")
    ap.add_argument("--box", type=float, default=0.5, help="side fraction of the centred box")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real", nargs="*", default=[], help="EVENTS:CALIB:GYRO real windows")
    ap.add_argument("--real-ms", type=int, default=1000, help="longest real window, ms")
    args = ap.parse_args()
    torch.set_num_threads(2)
    model, _ = load_checkpoint(args.checkpoint)
    model.eval()
    print(f"checkpoint {args.checkpoint}")
    windows: list[Window] = []
    if args.data:
        windows = fixed_windows(args.data, "test")[: args.windows]
        simulated(model, windows, args.keep, args.box, args.seed)
    for spec in args.real:
        window = real_recording(spec, args.real_ms)
        real(model, window)
        activity(model, window, windows)


if __name__ == "__main__":
    main()
