"""Event statistics against synthetic streams of known statistics, and ``compare-stats``."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from spikegyro.events import stats
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording


def poisson_events(width, height, rate_hz, seconds, on_prob=0.5, seed=0, hot=None):
    """Independent Poisson events per pixel at ``rate_hz``; ``hot`` = (x, y, rate) adds a pixel
    firing at its own rate."""
    rng = np.random.default_rng(seed)
    rates = np.full((height, width), float(rate_hz))
    if hot is not None:
        rates[hot[1], hot[0]] = hot[2]
    counts = rng.poisson(rates * seconds)
    y, x = np.nonzero(counts >= 0)
    x, y = np.repeat(x, counts[y, x]), np.repeat(y, counts[y, x])
    t = rng.uniform(0, seconds * 1e6, x.size).astype(np.int64)
    order = np.argsort(t, kind="stable")
    p = rng.random(x.size) < on_prob
    return EventArray.from_arrays(x[order], y[order], t[order], p[order], width, height)


def test_poisson_rates_polarity_and_intervals():
    rate, seconds = 40.0, 2.0
    ev = poisson_events(60, 40, rate, seconds, on_prob=0.3)
    s = stats.window_stats(ev, seconds * 1e6)
    pixels = 60 * 40
    # the mean of 2400 Poisson(80) counts: relative standard error 0.2 %
    assert s["rate_px_hz"] == pytest.approx(rate, rel=0.01)
    assert s["rate_per_ms"] == pytest.approx(rate * pixels / 1000, rel=0.01)
    assert s["coverage"] == 1.0
    assert s["on_fraction"] == pytest.approx(0.3, abs=0.01)
    # Intervals of a Poisson process are exponential: median ln 2 / rate, 10 % quantile
    # -ln 0.9 / rate; a share 1 - exp(-rate * 1 ms) is under 1 ms.
    assert s["iei_median_us"] == pytest.approx(np.log(2) / rate * 1e6, rel=0.02)
    assert s["iei_p10_us"] == pytest.approx(-np.log(0.9) / rate * 1e6, rel=0.03)
    assert s["iei_below_1ms"] == pytest.approx(1 - np.exp(-rate * 1e-3), rel=0.1)
    assert sum(s["iei_hist"]) == len(ev) - pixels  # n - 1 intervals per pixel
    assert sum(s["rate_hist"]) == pixels
    # uniform activity: the busiest 1 % of pixels fire a little over 1 % of the events
    assert 0.01 < s["top_share"]["0.01"] < 0.015


def test_hot_pixel_dominates_the_top_share():
    ev = poisson_events(50, 40, 2.0, 1.0, hot=(7, 9, 20_000.0), seed=1)
    counts = stats.pixel_counts(ev)
    assert counts[9, 7] == np.sum((ev.x == 7) & (ev.y == 9))
    assert abs(counts[9, 7] - 20_000) < 5 * np.sqrt(20_000)
    expected = counts[9, 7] / len(ev)  # 20,000 of about 24,000 events
    assert stats.top_pixel_share(counts, 1 / counts.size) == pytest.approx(expected)
    s = stats.window_stats(ev, 1e6)
    others = np.delete(counts.ravel(), 9 * 50 + 7)
    top_two = (counts[9, 7] + others.max()) / len(ev)  # 0.1 % of 2000 pixels
    assert s["top_share"]["0.001"] == pytest.approx(top_two, abs=1e-12)
    assert s["top_share"]["0.001"] > 0.8


def test_intervals_are_per_pixel():
    ev = EventArray.from_arrays([0, 1, 0, 1, 0], [0, 0, 0, 0, 0], [0, 5, 10, 11, 40],
                                [1, 0, 0, 1, 1], 2, 1)  # fmt: skip
    np.testing.assert_array_equal(stats.inter_event_intervals(ev), [10, 30, 6])
    assert stats.top_pixel_share(np.array([3, 1]), 0.5) == 0.75
    assert np.isnan(stats.top_pixel_share(np.zeros(4), 0.5))


def test_log_histogram_keeps_everything_and_pool_adds():
    edges = stats.IEI_EDGES_US
    counts = stats.log_histogram(np.array([0, 1, 10, 999, 5e6]), edges)
    assert counts.sum() == 5 and counts[0] == 2 and counts[-1] == 1
    ev = poisson_events(20, 10, 50.0, 0.3, seed=2)
    windows = [stats.window_stats(w, span) for w, span in stats.split_windows(ev, 100_000)]
    assert len(windows) == 2 or len(windows) == 3
    pooled = stats.pool(windows)
    assert pooled["events"] == sum(w["events"] for w in windows)
    assert pooled["iei_hist"] == np.sum([w["iei_hist"] for w in windows], axis=0).tolist()
    assert pooled["rate_per_ms"]["n"] == len(windows)
    assert pooled["rate_per_ms"]["min"] <= pooled["rate_per_ms"]["median"]


def test_split_windows():
    ev = EventArray.from_arrays([0] * 5, [0] * 5, [100, 150, 1099, 1100, 2500], [1] * 5, 1, 1)
    parts = stats.split_windows(ev, 1000)
    assert [(len(w), span) for w, span in parts] == [(3, 1000), (1, 1000)]  # 2500 left over
    short = stats.split_windows(ev[:2], 1000)
    assert [(len(w), span) for w, span in short] == [(2, 51)]
    assert stats.split_windows(ev[:0], 1000) == []


def test_compare_stats_command(tmp_path, monkeypatch, capsys):
    from spikegyro import cli

    sim_dir = tmp_path / "sim"
    for i, rate in enumerate((30.0, 60.0)):
        ev = poisson_events(40, 30, rate, 0.2, seed=i)
        gyro = GyroTrace.from_arrays([0, 200_000], np.zeros((2, 3)))
        write_recording(sim_dir / "test" / f"seq_{i:06d}.h5", Recording(ev, gyro))
    hot = poisson_events(40, 30, 10.0, 0.05, hot=(3, 4, 40_000.0), seed=5)
    real = write_recording(tmp_path / "cam", Recording(events=hot))
    out = tmp_path / "out"
    argv = ["spikegyro", "compare-stats", str(real), "--sim", str(sim_dir), "--out", str(out),
            "--window-ms", "100", "--width", "40", "--height", "30"]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    cli.main()
    result = json.loads((out / "stats.json").read_text())
    # each 200 ms sequence holds one whole 100 ms window from its first event
    assert result["sim"]["windows"] == 2 and result["sim"]["files"] == 2
    rates = result["sim"]["rate_px_hz"]
    assert rates["min"] == pytest.approx(30.0, rel=0.1) and rates["max"] == pytest.approx(
        60, rel=0.1
    )
    cam = result["real"]["cam"]
    # 2,000 hot events among about 2,600 (the hot pixel fires 40 kHz for 50 ms)
    assert cam["windows"] == 1 and cam["top_share"]["0.01"]["median"] > 0.75
    assert (out / "sim_vs_real.png").stat().st_size > 10_000
    capsys.readouterr()
    # bad input: one line, exit 2
    monkeypatch.setattr(sys, "argv", [*argv[:3], "--sim", str(tmp_path / "none"), "--out", "x"])
    with pytest.raises(SystemExit) as info:
        cli.main()
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.strip().count("\n") == 0 and "none" in err
