"""The paper's Figure 3: events in space-time above the angular velocity on three axes."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from spikegyro.events.core import EventArray
from spikegyro.events.io import atomic_path

AXIS_NAMES = ("tilt $\\omega_x$", "pan $\\omega_y$", "roll $\\omega_z$")
ON_COLOR, OFF_COLOR = "#d62728", "#1f4fb4"


def _default_t0_s(events: EventArray, omega_t_s: np.ndarray | None) -> float:
    """The plots' time origin, seconds: the first ω sample, else the first event, else 0."""
    if omega_t_s is not None and len(omega_t_s):
        return float(omega_t_s[0])
    return float(events.t[0]) / 1e6 if len(events) else 0.0


def _draw_events(ax: Any, events: EventArray, t0_s: float, max_events: int, zoom: float) -> None:
    """The space-time scatter (t in ms from ``t0_s``, x, y in px) on a 3-D axis, thinned
    evenly to at most ``max_events``, with a legend that says how many are drawn."""
    step = max(1, int(np.ceil(len(events) / max_events)))
    ev = events[::step]
    t_ms = (ev.t / 1e6 - t0_s) * 1e3
    for pol, color, name in ((1, ON_COLOR, "ON"), (0, OFF_COLOR, "OFF")):
        sel = ev.p == pol
        ax.scatter(t_ms[sel], ev.x[sel], ev.y[sel], s=1.0, c=color, alpha=0.5, linewidths=0,
                   depthshade=False, label=name)  # fmt: skip
    ax.set_xlabel("t [ms]")
    ax.set_ylabel("x [px]")
    ax.set_zlabel("y [px]")
    ax.set_ylim(0, events.width)
    ax.set_zlim(events.height, 0)  # image rows grow downwards
    ax.view_init(elev=18, azim=-62)
    ax.set_box_aspect((2.4, 1.0, events.height / events.width), zoom=zoom)
    handles = [
        Line2D([], [], ls="", marker="o", color=c, label=n)
        for c, n in ((ON_COLOR, "ON"), (OFF_COLOR, "OFF"))
    ]
    shown = f"{len(ev):,} of {len(events):,} events" if step > 1 else f"{len(events):,} events"
    ax.legend(
        handles=handles, loc="upper right", title=shown, fontsize=8, title_fontsize=8, frameon=False
    )


def _draw_omega(
    fig: Figure,
    cells: list[Any],
    t_ms: np.ndarray,
    omega_true: np.ndarray | None,
    omega_pred: np.ndarray | None,
) -> None:
    """One panel per axis under the events: true ω solid, predicted dashed, deg/s against ms."""
    shared = None
    for k, cell in enumerate(cells):
        a = fig.add_subplot(cell, sharex=shared)
        shared = shared or a
        if omega_true is not None:
            a.plot(t_ms, np.degrees(np.asarray(omega_true)[:, k]), "k-", lw=1.5, label="true")
        if omega_pred is not None:
            a.plot(t_ms, np.degrees(np.asarray(omega_pred)[:, k]), "--", color="tab:orange",
                   lw=1.5, label="predicted")  # fmt: skip
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
        t0_s = _default_t0_s(events, omega_t_s)
    has_omega = omega_true is not None or omega_pred is not None
    fig = Figure(figsize=(8.0, 9.5 if has_omega else 5.5), layout="constrained")
    grid = fig.add_gridspec(
        4 if has_omega else 1, 1, height_ratios=[2.4, 1, 1, 1][: 4 if has_omega else 1]
    )
    ax = fig.add_subplot(grid[0], projection="3d")
    _draw_events(ax, events, t0_s, max_events, zoom=1.2 if has_omega else 1.05)
    if title:
        fig.suptitle(title)
    if has_omega:
        t_ms = (np.asarray(omega_t_s, dtype=np.float64) - t0_s) * 1e3
        _draw_omega(fig, [grid[k + 1] for k in range(3)], t_ms, omega_true, omega_pred)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=130, format=out.suffix.lstrip(".") or "png")
    return out


_STAT_PANELS = (
    ("rate_per_ms", "event rate [events/ms]", True),
    ("on_fraction", "ON fraction [-]", False),
    ("top_share", "share of events from the 1 % most active pixels [-]", False),
    ("coverage", "pixels with an event [-]", False),
)
_REAL_COLORS = ("#D55E00", "#0072B2", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")


def _window_value(stats: dict, key: str) -> float | None:
    return stats["top_share"]["0.01"] if key == "top_share" else stats[key]


def stats_figure(
    real: dict[str, list[dict]],
    sim: list[dict],
    iei_edges_us: np.ndarray,
    rate_edges_hz: np.ndarray,
    sim_label: str = "simulator",
) -> Figure:
    """Event statistics of real recordings against the simulator's (overlaid histograms).

    Args:
        real: recording name -> its windows' :func:`spikegyro.events.stats.window_stats`.
        sim: the simulated windows' statistics.
        iei_edges_us, rate_edges_hz: the histogram bins those statistics use.

    Four panels show a per-window statistic: the simulator's windows as a grey histogram, each
    real window as a colored tick (a recording's median as a dashed line). Two panels show the
    pooled distributions of inter-event intervals per pixel and of per-pixel event rates, as the
    share of intervals (pixels) per bin.
    """
    fig = Figure(figsize=(13.0, 7.6))
    axes = fig.subplots(2, 3).ravel()
    colors = {name: _REAL_COLORS[i % len(_REAL_COLORS)] for i, name in enumerate(real)}
    for ax, (key, label, log) in zip(axes[:4], _STAT_PANELS, strict=True):
        sim_v = np.array([v for w in sim if (v := _window_value(w, key)) is not None])
        real_v = {n: [v for w in ws if (v := _window_value(w, key)) is not None]
                  for n, ws in real.items()}  # fmt: skip
        everything = np.concatenate([sim_v, *[np.array(v) for v in real_v.values()]])
        lo, hi = (everything.min(), everything.max()) if everything.size else (0.0, 1.0)
        if log:
            lo = max(lo, 1e-3)
            bins = np.logspace(np.log10(lo) - 0.05, np.log10(max(hi, lo * 1.01)) + 0.05, 30)
            ax.set_xscale("log")
        else:
            pad = 0.05 * max(hi - lo, 1e-3)
            bins = np.linspace(lo - pad, hi + pad, 30)
        ax.hist(sim_v, bins=bins, color="0.7", edgecolor="0.5", label=f"{sim_label} windows")
        top = ax.get_ylim()[1]
        for name, values in real_v.items():
            if not values:
                continue
            ax.vlines(values, 0, 0.12 * top, color=colors[name], lw=1.5)
            ax.axvline(float(np.median(values)), color=colors[name], ls="--", lw=1.2, label=name)
        ax.set_xlabel(label)
        ax.set_ylabel("windows")
        ax.grid(alpha=0.3)
    for ax, key, edges, label in (
        (axes[4], "iei_hist", iei_edges_us, "inter-event interval per pixel [µs]"),
        (axes[5], "rate_hist", rate_edges_hz, "event rate of a pixel that fired [events/s]"),
    ):
        centres = np.sqrt(edges[1:] * edges[:-1])
        total = np.sum([w[key] for w in sim], axis=0)
        if total.sum():
            ax.fill_between(centres, total / total.sum(), step="mid", color="0.75",
                            label=sim_label)  # fmt: skip
        for name, windows in real.items():
            counts = np.sum([w[key] for w in windows], axis=0)
            if counts.sum():
                ax.step(centres, counts / counts.sum(), where="mid", color=colors[name], lw=1.4,
                        label=name)  # fmt: skip
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("share per bin (10 bins/decade)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper left")
    axes[4].legend(fontsize=7, loc="upper left")
    fig.suptitle("Event statistics: real recordings (colors) against the simulator (grey)")
    fig.tight_layout()
    return fig
