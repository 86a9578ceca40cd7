"""The global search's grid on real windows: the first-order warp with nearest-pixel votes
(``iwe.grid_contrast``, what ships) against the exact warp with bilinear votes (``iwe.contrast``
per grid point, the scoring it replaced), same run, one thread, CPU time.

For windows of ``--window-ms`` every ``--every-s`` of a recording (events as rays, at the
defaults of ``CMaxConfig``): the CPU time of scoring the 11³ grid both ways, of the whole
``search`` as it ships, and whether the two scorings pick the same best grid point, and how far
apart the search's ω lands with either scoring picking its starts.

    python bench/cmax_grid.py ../shared/real/unlabeled/davis240_rotbars/events.txt \\
        --intrinsics 245 245 120 90
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from spikegyro.cmax import iwe, search
from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.problem import Problem, make_problem
from spikegyro.events.calib import PinholeCamera
from spikegyro.events.io import read_recording


def exact_scores(p: Problem, grid: np.ndarray, rest: tuple) -> np.ndarray:
    """The grid scored with the exact warp and bilinear votes."""
    return np.array([iwe.contrast(p.bx, p.by, p.dt, p.weights, w, *rest, False)[0] for w in grid])


def exact_grid_starts(problem: Problem, config: CMaxConfig) -> list[np.ndarray]:
    """``search._grid_starts`` with the exact scoring."""
    grid, rest = search.grid_of(problem, config)
    return list(grid[np.argsort(-exact_scores(problem, grid, rest))[: config.starts]])


def cpu(function: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """(result, CPU seconds of this thread)."""
    start = time.thread_time()
    out = function(*args)
    return out, time.thread_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("events", type=Path)
    parser.add_argument("--intrinsics", nargs=4, type=float, default=[245, 245, 120, 90])
    parser.add_argument("--window-ms", type=float, default=100.0)
    parser.add_argument("--every-s", type=float, default=0.5)
    args = parser.parse_args()
    events = read_recording(args.events).events
    camera = PinholeCamera(events.width, events.height, *args.intrinsics)
    config = CMaxConfig()
    rng = np.random.default_rng(0)
    rows = []
    for t in np.arange(events.t[0] + args.window_ms * 1e3, events.t[-1], args.every_s * 1e6):
        window = events.slice_time(int(t - args.window_ms * 1e3), int(t))
        if len(window) < config.min_events:
            continue
        problem = make_problem(window, camera, config, rng, None)
        sub = problem.subset(config.search_events, rng).subset(config.grid_events, rng)
        grid, rest = search.grid_of(sub, config)
        exact, t_exact = cpu(exact_scores, sub, grid, rest)
        first, t_first = cpu(iwe.grid_contrast, sub.bx, sub.by, sub.dt, sub.weights, grid, *rest)
        found, t_search = cpu(search.search, problem, config, None, True, np.random.default_rng(1))
        shipped, search._grid_starts = search._grid_starts, exact_grid_starts
        try:
            best = search.search(problem, config, None, True, np.random.default_rng(1))
        finally:
            search._grid_starts = shipped
        apart = math.degrees(float(np.linalg.norm(found.omega - best.omega)))
        rows.append((t_exact, t_first, t_search, exact.argmax() == first.argmax(), apart))
    t_exact, t_first, t_search, same, apart = (np.array(c) for c in zip(*rows, strict=True))
    print(f"{args.events}: {len(rows)} windows of {args.window_ms:g} ms, grid of "
          f"{config.grid_points}³ on {config.grid_events} events")  # fmt: skip
    print(f"grid, exact warp + bilinear votes: {1e3 * np.median(t_exact):.1f} ms CPU (median)")
    print(f"grid, first-order warp + nearest votes: {1e3 * np.median(t_first):.1f} ms CPU "
          f"(median); {np.median(t_exact / t_first):.2f}x faster")  # fmt: skip
    print(f"whole search as it ships: {1e3 * np.median(t_search):.1f} ms CPU (median)")
    print(f"same best grid point: {same.mean():.0%} of windows; search ω with either scoring "
          f"apart by median {np.median(apart):.2f}, max {apart.max():.2f} deg/s")  # fmt: skip


if __name__ == "__main__":
    main()
