"""Score SNN checkpoints, CMax and omega = 0 on the real recordings of this folder's README.

    python runs/selfsup-real/score.py REAL_DIR OUT_JSON NAME=CHECKPOINT[,OPTION...] ...

Options after the checkpoint go to ``spikegyro predict``, e.g. ``clock=CKPT,--pixels,sensor``
or ``snn6-clock=snn6,--clock,events:1000``.

REAL_DIR holds rueckauer2016_translBoxes/, ecd_windows/shapes_rotation/ and
unlabeled/davis240_rotbars/. Every number comes from ``spikegyro predict`` (the command on
PATH): per estimate from 50 ms after the scored span's start on, against the reference
interpolated at the estimate's time, per-axis mean absolute error and mean Euclidean error,
deg/s; ``zero_euclid`` is ω = 0's; ``lag_ms`` is the shift of the reference that best
correlates with the estimates (positive: the estimates lag; NaN where the best is at the edge
of ±400 ms, as on a steady motion). References: translBoxes' gyro
with its +3.5 deg/s tilt bias removed (the bias the camera shows at rest), the shapes window's
motion capture, and offline CMax on rot_bars' held-out tail (from 5.43 s: the last 20 %, never
trained on) and second half (from 3.39 s, what ``adapt`` on the first half is scored on).
Results accumulate in OUT_JSON.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TILT_BIAS_RAD_S = np.radians(3.5)
ROT_BARS_INTRINSICS = ["--intrinsics", "245", "245", "120", "90"]


def recordings(real: Path) -> dict[str, dict]:
    """Each scored recording: its path, calibration options, reference and scored span."""
    boxes, shapes = real / "rueckauer2016_translBoxes", real / "ecd_windows" / "shapes_rotation"
    bars = str(real / "unlabeled" / "davis240_rotbars" / "events.txt")
    return {
        "translBoxes": dict(path=str(boxes / "events.txt"), cam=ROT_BARS_INTRINSICS,
                            ref=boxes / "gyro.txt", start=0.0),
        "shapes": dict(path=str(shapes), cam=[], ref=shapes / "gyro_from_mocap.txt", start=0.0),
        "rot_bars_tail": dict(path=bars, cam=ROT_BARS_INTRINSICS, ref=None, start=5.43),
        "rot_bars_second_half": dict(path=bars, cam=ROT_BARS_INTRINSICS, ref=None, start=3.39),
    }  # fmt: skip


def predict(rec: dict, options: list[str], out: Path) -> np.ndarray:
    """``spikegyro predict`` of ``rec`` from its start: rows (t s, wx, wy, wz rad/s)."""
    command = ["spikegyro", "predict", rec["path"], *rec["cam"], "-o", str(out)]
    subprocess.run([*command, "--start", str(rec["start"]), *options], check=True,
                   capture_output=True, text=True)  # fmt: skip
    with open(out) as f:
        rows = [[float(r[k]) for k in ("t", "wx", "wy", "wz")] for r in csv.DictReader(f)]
    return np.array(rows)


def reference(rec: dict, offline: np.ndarray) -> np.ndarray:
    """Rows (t s, wx, wy, wz rad/s) of the recording's reference."""
    if rec["ref"] is None:
        return offline
    ref = np.loadtxt(rec["ref"])[:, :4]
    if "translBoxes" in str(rec["ref"]):
        ref[:, 1] -= TILT_BIAS_RAD_S
    return ref


def first_event_s(path: str) -> float:
    """Time of a text recording's first event, s."""
    p = Path(path)
    with open(p / "events.txt" if p.is_dir() else p) as f:
        return float(f.readline().split()[0])


def score(est: np.ndarray, ref: np.ndarray, t0: float) -> dict[str, float]:
    """Errors of estimates ``est`` from ``t0 + 50 ms`` on against ``ref``, deg/s."""
    e = est[est[:, 0] >= t0 + 0.05]
    truth = np.stack([np.interp(e[:, 0], ref[:, 0], ref[:, k]) for k in (1, 2, 3)], axis=1)
    d = np.degrees(e[:, 1:] - truth)
    mae = np.abs(d).mean(axis=0)
    return dict(n=len(e), tilt=float(mae[0]), pan=float(mae[1]), roll=float(mae[2]),
                euclid=float(np.linalg.norm(d, axis=1).mean()),
                zero_euclid=float(np.degrees(np.linalg.norm(truth, axis=1)).mean()),
                lag_ms=lag_ms(e, ref))  # fmt: skip


def lag_ms(est: np.ndarray, ref: np.ndarray, max_ms: int = 400) -> float:
    """The delay (ms, 1 ms steps) of the reference that correlates best with the estimates,
    all axes together, each centred (positive: the estimates lag the reference)."""
    grid = np.arange(est[0, 0], est[-1, 0], 1e-3)
    if len(grid) < 3 * max_ms:
        return float("nan")
    a = np.stack([np.interp(grid, est[:, 0], est[:, k]) for k in (1, 2, 3)], axis=1)
    a -= a.mean(axis=0)
    scores = []
    for lag in range(-max_ms, max_ms + 1):
        b = np.stack([np.interp(grid - lag * 1e-3, ref[:, 0], ref[:, k]) for k in (1, 2, 3)], 1)
        b -= b.mean(axis=0)
        scores.append(float((a * b).sum() / (np.linalg.norm(a) * np.linalg.norm(b) + 1e-12)))
    best = int(np.argmax(scores))
    # a peak at the edge of the search is no peak: the motion does not vary enough to time it
    return float(best - max_ms) if 0 < best < 2 * max_ms else float("nan")


def main() -> None:
    if len(sys.argv) < 4:
        sys.exit(__doc__.strip().splitlines()[2].strip())
    real, out_json = Path(sys.argv[1]), Path(sys.argv[2])
    checkpoints = {k: v.split(",") for k, v in (a.split("=", 1) for a in sys.argv[3:])}
    work = out_json.parent / "score_work"
    work.mkdir(parents=True, exist_ok=True)
    results = json.loads(out_json.read_text()) if out_json.exists() else {}
    for name, rec in recordings(real).items():
        t0 = first_event_s(rec["path"]) + rec["start"]
        offline = predict(rec, ["--method", "cmax", "--offline"], work / f"{name}-cmax.csv")
        ref = reference(rec, offline)
        methods = {
            f"snn:{k}": ["--method", "snn", "--checkpoint", v[0], *v[1:]]
            for k, v in checkpoints.items()
        }
        if rec["ref"] is not None:
            results.setdefault(name, {})["cmax-offline"] = score(offline, ref, t0)
            methods["cmax-live"] = ["--method", "cmax"]
        for label, options in methods.items():
            est = predict(rec, options, work / f"{name}-{label.replace(':', '-')}.csv")
            results.setdefault(name, {})[label] = score(est, ref, t0)
            print(name, label, {k: round(v, 1) for k, v in results[name][label].items()})
            out_json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
