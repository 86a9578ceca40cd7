"""The outputs of ``spikegyro evaluate-real`` (:mod:`spikegyro.evaluate.real`): per-ms and
per-window CSV tables, figures, and the report (HTML and Markdown) built from ``metrics.json``'s
content. Angular velocity is in rad/s in files and deg/s in tables and figures."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from spikegyro.evaluate import figures
from spikegyro.evaluate.report import (
    Block,
    FigureRef,
    Table,
    axis_table,
    bin_table,
    metric_cells,
    metric_header,
    write_report,
)
from spikegyro.events.core import GyroTrace
from spikegyro.events.io import atomic_path, recording_name
from spikegyro.events.windows import BIN_US

_REPORT_WINDOW_ROWS = 40


def _write_csv(path: Path, head: list[str], cols: list[np.ndarray]) -> None:
    """A CSV table of the columns (1-D, or 2-D for several) under a header row, atomically."""
    with atomic_path(path) as tmp:
        np.savetxt(tmp, np.column_stack(cols), delimiter=",", header=",".join(head),
                   comments="", fmt="%.9g")  # fmt: skip


def write_tables(
    out_dir: Path,
    ends: np.ndarray,
    scored: np.ndarray,
    gt: np.ndarray,
    per_ms: dict[str, tuple[str, np.ndarray]],
    w_starts: np.ndarray,
    w_ends: np.ndarray,
    num_events: np.ndarray,
    win_ok: np.ndarray,
    w_gt: np.ndarray,
    window_pred: dict[str, np.ndarray],
) -> None:
    """predictions.csv (per ms) and windows.csv (per window); angular velocity in rad/s."""
    axes = ("wx", "wy", "wz")
    keys = {"snn": "snn", "cmax": "cmax", "cmax_live": "cmax_live", "mean": "mean"}
    head = ["t", "scored"] + [f"gyro_{a}" for a in axes]
    cols = [ends / 1e6, scored.astype(int), gt]
    for method, series in per_ms.values():
        head += [f"{keys[method]}_{a}" for a in axes]
        cols.append(series)
    _write_csv(out_dir / "predictions.csv", head, cols)
    tags = {name: ("cmax_window" if name == "CMax (window)" else per_ms[name][0])
            for name in window_pred}  # fmt: skip
    head = ["start", "end", "events", "scored"] + [f"gyro_{a}" for a in axes]
    cols = [w_starts / 1e6, w_ends / 1e6, num_events, win_ok.astype(int), w_gt]
    for name, pred in window_pred.items():
        head += [f"{tags[name]}_{a}" for a in axes]
        cols.append(pred)
    _write_csv(out_dir / "windows.csv", head, cols)


def write_figures(
    out_dir: Path,
    result: dict[str, Any],
    t0: int,
    ends: np.ndarray,
    per_ms: dict[str, tuple[str, np.ndarray]],
    trace: GyroTrace,
    w_starts: np.ndarray,
    w_ends: np.ndarray,
    cmax_win: np.ndarray,
) -> None:
    models = result["models"]
    warmup = result["data"]["warmup_ms"]
    inside = (trace.t >= t0 - 5 * BIN_US) & (trace.t <= ends[-1] + 5 * BIN_US)
    figures.save_figure(
        figures.omega_traces(
            (ends - t0) / 1000,
            {name: np.degrees(series) for name, (_, series) in per_ms.items()},
            ((trace.t[inside] - t0) / 1000, np.degrees(trace.omega[inside])),
            {
                "CMax (window)": (
                    (w_starts - t0) / 1000,
                    (w_ends - t0) / 1000,
                    np.degrees(cmax_win),
                )
            },
            shade_until_ms=warmup,
            title=recording_name(Path(result["data"]["recording"])),
        ),
        out_dir / "traces.png",
    )
    fit = result["gyro"]["offset_fit"]
    if fit["offset_us"] is not None:
        figures.save_figure(
            figures.offset_curve(
                np.array(fit["offsets_us"]) / 1000,
                np.array([np.nan if c is None else c for c in fit["correlations"]]),
                fit["offset_us"] / 1000,
                result["gyro"]["offset_applied_us"] / 1000,
            ),
            out_dir / "offset.png",
        )
    per_bin = {name: m["per_bin"] for name, m in models.items() if m["metrics"] is not None}
    figures.save_figure(
        figures.median_relative_error_per_bin(per_bin, "Real recording: per speed bin"),
        out_dir / "bins.png",
    )
    for name, (method, _) in per_ms.items():
        if method != "mean":
            figures.save_figure(
                figures.axis_relative_error_boxes(models[name]["per_bin"], name),
                out_dir / f"axes_{method}.png",
            )


def _window_table(result: dict[str, Any]) -> Table:
    w = result["data"]["windows"]
    omega = result["windows_omega_rad_s"]
    names = [n for n in omega if n != "gyro"]
    rows = []
    for i in range(min(w["count"], _REPORT_WINDOW_ROWS)):
        gyro = np.degrees(omega["gyro"][i])
        cells = [
            f"{(w['start_s'][i] - result['data']['t0_s']) * 1e3:.1f}–"
            f"{(w['end_s'][i] - result['data']['t0_s']) * 1e3:.1f}",
            f"{w['events'][i]:,}",
            " / ".join(f"{v:+.0f}" for v in gyro),
        ]
        for name in names:
            err = np.degrees(np.linalg.norm(np.array(omega[name][i]) - omega["gyro"][i]))
            est = " / ".join(f"{v:+.0f}" for v in np.degrees(omega[name][i]))
            cells.append(f"{est} ({err:.0f})")
        rows.append(cells)
    more = (
        f" (first {_REPORT_WINDOW_ROWS} of {w['count']}; all in windows.csv)"
        if (w["count"] > _REPORT_WINDOW_ROWS)
        else ""
    )
    return Table(
        "Per window: mean tilt / pan / roll [deg/s] and, in brackets, the Euclidean error "
        f"against the gyro's mean [deg/s]{more}",
        ["window [ms from start]", "events", "gyro", *names],
        rows,
    )


def _offset_text(gyro: dict[str, Any]) -> str:
    """The clock offset fit in words: the best offset and how sure it is, and what is applied."""
    fit = gyro["offset_fit"]
    if fit["offset_us"] is None:
        return f"No clock offset could be fitted: {fit['reason']}"
    return (
        f"Best clock offset: {fit['offset_us'] / 1000:+.2f} ms (normalised cross-correlation "
        f"{fit['correlation']:.3f}, at 0 ms {fit['correlation_at_zero']:.3f}; "
        f"{fit['n_estimates']} CMax estimates over {fit['step_us'] / 1000:g} ms steps of "
        f"±{fit['max_offset_us'] / 1000:g} ms). Applied: "
        f"{gyro['offset_applied_us'] / 1000:+.2f} ms. Apply the best fit with --gyro-offset "
        "auto, or any value with --gyro-offset MS (added to the gyro's timestamps)."
    )


def write_real_report(out_dir: Path, result: dict[str, Any]) -> None:
    """report.html and report.md from ``result`` (metrics.json's content) and the figures
    already in ``out_dir``."""
    data, gyro, models = result["data"], result["gyro"], result["models"]
    win = data["windows"]
    per_ms_models = {n: m for n, m in models.items() if m["metrics"] is not None}
    snn_name = next(n for n, m in models.items() if m["method"] == "snn")
    unit = "events" if win["by"] == "events" else "ms"
    interval = gyro["sampling_interval"]
    rotation = (
        "as given (camera frame)"
        if gyro["imu_to_camera"] is None
        else "rotated into the camera frame by R = "
        + str(np.round(np.array(gyro["imu_to_camera"]), 4).tolist())
    )
    blocks: list[Block] = [
        f"Recording: {data['recording']} ({data['sensor'][0]}x{data['sensor'][1]}, calibration "
        f"{data['calibration'] or 'none: the simulator pinhole'}), {data['events']:,} events over "
        f"{data['steps_ms']} ms ({data['event_rate_per_s'] / 1e6:.2f} M events/s) from "
        f"t = {data['t0_s']:.6f} s. Metrics count from {data['warmup_ms']} ms on "
        f"({data['scored_steps']} steps), after the SNN's warm-up.",
        f"Gyro: {gyro['source']}, {gyro['samples']:,} samples, {rotation}; sampled every "
        f"{interval['median_us'] / 1000:.3f} ms (median; {interval['min_us'] / 1000:.3f} to "
        f"{interval['max_us'] / 1000:.3f} ms, {interval['rate_hz']:.0f} Hz), interpolated "
        "linearly to each 1 ms step's end; per window, its exact mean over the window.",
        f"Windows: {win['count']} of {win['size']:,} {unit} from the end of the warm-up "
        f"({win['scored']} inside the gyro's span). Mean predictor: "
        + ", ".join(f"{v:+.2f}" for v in np.degrees(models["Mean"]["omega_rad_s"]))
        + f" deg/s ({models['Mean']['source']}). CMax (window): one contrast-maximization "
        "estimate from all the events of each window.",
        *[f"Warning: {w}" for w in result["warnings"]],
        "## Clock offset between gyro and events",
        _offset_text(gyro),
    ]
    if (out_dir / "offset.png").exists():
        blocks.append(
            FigureRef(
                "Cross-correlation of CMax (short windows) with the gyro against the offset "
                "added to the gyro's timestamps.",
                "offset.png",
            )
        )
    blocks += [
        "## Overall",
        Table(
            "Errors against the gyro: per ms (each model's output at each step's end) and per "
            "window (each model's mean over the window against the gyro's mean)",
            ["model", *metric_header("per window")],
            [[name, *metric_cells(m)] for name, m in models.items()],
        ),
        axis_table({name: m["metrics"] for name, m in per_ms_models.items()}),
        FigureRef(
            "Angular velocity against time: the gyro (black, with its samples), each model per "
            "ms, and CMax's one estimate per window (thick segments).",
            "traces.png",
        ),
        "## Per window",
        _window_table(result),
        "## Per speed",
        bin_table({name: m["per_bin"] for name, m in per_ms_models.items()}),
        FigureRef("Median relative error per true-speed bin (paper Fig. 4).", "bins.png"),
    ]
    for name, m in per_ms_models.items():
        if m["method"] != "mean":
            blocks.append(
                FigureRef(
                    f"{name}: signed per-axis relative error per speed bin (paper Fig. 5).",
                    f"axes_{m['method']}.png",
                )
            )
    write_report(out_dir, f"spikegyro real-data evaluation: {snn_name}, CMax, mean", blocks)
