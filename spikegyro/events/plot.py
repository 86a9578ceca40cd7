"""The paper's Figure 3: events in space-time above the angular velocity on three axes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from spikegyro.events.core import EventArray
from spikegyro.events.io import atomic_path

AXIS_NAMES = ("tilt $\\omega_x$", "pan $\\omega_y$", "roll $\\omega_z$")
ON_COLOR, OFF_COLOR = "#d62728", "#1f4fb4"


def plot_events_and_omega(
    events: EventArray,
    omega_t_s: np.ndarray | None,
    omega_true: np.ndarray | None,
    omega_pred: np.ndarray | None = None,
    out: str | os.PathLike = "events.png",
    title: str | None = None,
    max_events: int = 40_000,
    t0_s: float | None = None,
) -> Path:
    """Save a figure: a 3-D space-time scatter of ``events`` (ON red, OFF blue) above ω(t).

    Args:
        events: the events to draw (t in µs); more than ``max_events`` are evenly thinned.
        omega_t_s: times of the ω samples, seconds (K,).
        omega_true: ground-truth ω, (K, 3) rad/s, drawn solid in deg/s; None draws events only.
        omega_pred: predicted ω, (K, 3) rad/s, drawn dashed.
        out: image path (format from the extension), written atomically.
        title: figure title.
        max_events: cap on drawn events.
        t0_s: time origin of the plots, seconds (default: the first ω sample or event).

    Returns:
        The path written.
    """
    out = Path(out)
    if t0_s is None:
        if omega_t_s is not None and len(omega_t_s):
            t0_s = float(omega_t_s[0])
        else:
            t0_s = float(events.t[0]) / 1e6 if len(events) else 0.0
    has_omega = omega_true is not None or omega_pred is not None
    fig = Figure(figsize=(8.0, 9.5 if has_omega else 5.5), layout="constrained")
    grid = fig.add_gridspec(
        4 if has_omega else 1, 1, height_ratios=[2.4, 1, 1, 1][: 4 if has_omega else 1]
    )
    ax = fig.add_subplot(grid[0], projection="3d")
    step = max(1, int(np.ceil(len(events) / max_events)))
    ev = events[::step]
    t_ms = (ev.t / 1e6 - t0_s) * 1e3
    for pol, color, name in ((1, ON_COLOR, "ON"), (0, OFF_COLOR, "OFF")):
        sel = ev.p == pol
        ax.scatter(
            t_ms[sel],
            ev.x[sel],
            ev.y[sel],
            s=1.0,
            c=color,
            alpha=0.5,
            linewidths=0,
            depthshade=False,
            label=name,
        )
    ax.set_xlabel("t [ms]")
    ax.set_ylabel("x [px]")
    ax.set_zlabel("y [px]")
    ax.set_ylim(0, events.width)
    ax.set_zlim(events.height, 0)  # image rows grow downwards
    ax.view_init(elev=18, azim=-62)
    ax.set_box_aspect((2.4, 1.0, events.height / events.width), zoom=1.2 if has_omega else 1.05)
    handles = [
        Line2D([], [], ls="", marker="o", color=c, label=n)
        for c, n in ((ON_COLOR, "ON"), (OFF_COLOR, "OFF"))
    ]
    shown = f"{len(ev):,} of {len(events):,} events" if step > 1 else f"{len(events):,} events"
    ax.legend(
        handles=handles, loc="upper right", title=shown, fontsize=8, title_fontsize=8, frameon=False
    )
    if title:
        fig.suptitle(title)
    if has_omega:
        t_w = (np.asarray(omega_t_s, dtype=np.float64) - t0_s) * 1e3
        shared = None
        for k in range(3):
            a = fig.add_subplot(grid[k + 1], sharex=shared)
            shared = shared or a
            if omega_true is not None:
                a.plot(t_w, np.degrees(np.asarray(omega_true)[:, k]), "k-", lw=1.5, label="true")
            if omega_pred is not None:
                a.plot(
                    t_w,
                    np.degrees(np.asarray(omega_pred)[:, k]),
                    "--",
                    color="tab:orange",
                    lw=1.5,
                    label="predicted",
                )
            lo, hi = a.get_ylim()
            if hi - lo < 40:  # keep small drifts from looking like large swings
                mid = 0.5 * (lo + hi)
                a.set_ylim(mid - 20, mid + 20)
            a.set_ylabel(f"{AXIS_NAMES[k]}\n[deg/s]")
            a.grid(alpha=0.3)
            if k == 0:
                a.legend(loc="best", fontsize=8)
            if k < 2:
                a.tick_params(labelbottom=False)
        a.set_xlabel("t [ms]")
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=130, format=out.suffix.lstrip(".") or "png")
    return out
