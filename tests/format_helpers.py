"""Shared checks of the camera-format tests: events read back, and the CLI's one-line errors."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from spikegyro.events import EventArray

REAL = Path(__file__).resolve().parents[2] / "shared" / "real" / "formats"
"""Real camera files (``../shared/real/formats`` beside the repository); tests skip without."""
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/real/formats is absent")


def assert_events(events: EventArray, x, y, t, p) -> None:
    """``events`` hold exactly the given events, in time order (stable for equal times)."""
    order = np.argsort(np.asarray(t), kind="stable")
    for name, want in zip("xytp", (x, y, t, p), strict=True):
        np.testing.assert_array_equal(getattr(events, name), np.asarray(want)[order], err_msg=name)


def cli_error(monkeypatch, capsys, *args: str) -> str:
    """Run the command line in-process; assert exit 2 with one line on stderr, and return it."""
    from spikegyro import cli

    monkeypatch.setattr(sys, "argv", ["spikegyro", *args])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0
    return err


def cli_run(monkeypatch, capsys, *args: str) -> tuple[str, str]:
    """Run the command line in-process; assert it succeeds, and return (stdout, stderr)."""
    from spikegyro import cli

    monkeypatch.setattr(sys, "argv", ["spikegyro", *args])
    monkeypatch.setenv("COLUMNS", "200")  # rich tables: no wrapped rows
    try:
        cli.main()
    except SystemExit as exc:
        assert not exc.code, capsys.readouterr().err
    captured = capsys.readouterr()
    return captured.out, captured.err
