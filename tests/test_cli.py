"""The command line's error contract: one line on stderr and a non-zero exit, no traceback."""

from __future__ import annotations

import subprocess
import sys


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "spikegyro", *args], capture_output=True, text=True, timeout=120
    )


def test_unknown_option_is_a_usage_error_not_a_traceback() -> None:
    res = _run("info", "--no-such-option")
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert "No such option: --no-such-option" in res.stderr


def test_missing_input_file_is_one_line_and_exit_2(tmp_path) -> None:
    res = _run("info", str(tmp_path / "missing.h5"))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "missing.h5" in lines[0]


def test_version_prints_and_exits_0() -> None:
    from spikegyro import __version__

    res = _run("--version")
    assert res.returncode == 0 and res.stdout.strip() == __version__


def test_exit_code_returned_by_a_command_is_kept(monkeypatch) -> None:
    """Typer returns a command's typer.Exit code instead of exiting; run() must pass it on."""
    from spikegyro import cli

    calls = []
    monkeypatch.setattr(type(cli.app), "__call__", lambda self, **k: calls.append(k) or 130)
    assert cli.run(["train"]) == 130 and calls


def test_numba_wrapped_ctrl_c_counts_as_an_interrupt() -> None:
    from spikegyro.errors import is_interrupt

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("returned a result with an exception set") from None
    except SystemError as exc:
        wrapped = exc
    assert is_interrupt(wrapped)
    assert not is_interrupt(SystemError("a real bug"))
    assert not is_interrupt(ValueError("bad value"))


def test_only_the_root_command_could_offer_completion() -> None:
    """Shell completion is installed for `spikegyro` as a whole; a sub-command offering
    --install-completion in its help would install it under the wrong name."""
    import typer

    from spikegyro.cli import _COMMANDS, app

    group = typer.main.get_command(app)
    ctx = group.make_context("spikegyro", ["--help"], resilient_parsing=True)
    for name in _COMMANDS:
        command = group.get_command(ctx, name)
        commands = getattr(command, "commands", {name: command})
        for sub in [command, *commands.values()]:
            options = {o for p in sub.params for o in getattr(p, "opts", [])}
            assert "--install-completion" not in options, name
