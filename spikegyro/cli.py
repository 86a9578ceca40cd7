"""The ``spikegyro`` command line: one Typer app over every stage of the pipeline.

Each stage keeps its commands in its own ``commands`` module; this file only wires them up and
keeps the error contract for all of them in one place (:func:`run`): bad input
(:class:`~spikegyro.errors.InputError` or a usage error) is one line ``error: ...`` on stderr and
exit code 2; Ctrl-C is one line and exit code 130; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import importlib
import inspect
import os
import sys
import warnings
from collections.abc import Sequence
from typing import Any

import typer
from typer.core import TyperGroup

from spikegyro import __version__
from spikegyro.errors import (
    InputError,
    InputWarning,
    Interrupted,
    check_interrupt,
    install_sigint_handler,
    interrupt_pending,
    is_interrupt,
)

_COMMANDS: dict[str, str] = {
    "info": "spikegyro.events.commands:info",
    "convert": "spikegyro.events.commands:convert_command",
    "compare-stats": "spikegyro.events.commands:compare_stats",
    "demo": "spikegyro.demo.commands:demo_command",
    "simulate": "spikegyro.sim.commands:simulate_dataset",
    "export-official": "spikegyro.sim.commands:export_official_command",
    "show": "spikegyro.sim.commands:show",
    "evaluate": "spikegyro.evaluate.commands:evaluate",
    "evaluate-real": "spikegyro.evaluate.commands:evaluate_real",
    "report": "spikegyro.evaluate.commands:report",
    "export-nir": "spikegyro.models.commands:export_nir_command",
    "train": "spikegyro.train.commands:train_command",
    "relay-log": "spikegyro.train.commands:relay_log_command",
    "adapt": "spikegyro.train.commands:adapt_command",
    "predict": "spikegyro.cmax.commands:predict",
    "baseline": "spikegyro.cmax.commands:app",
    "calibrate-imu": "spikegyro.cmax.commands:calibrate_imu",
}
"""Command name -> ``module:attribute`` (a command function or a Typer sub-app). A stage's module
is imported only when its command runs or ``--help`` lists it, so ``spikegyro predict`` does not
pay for torch or matplotlib."""


class _LazyGroup(TyperGroup):
    def invoke(self, ctx: typer.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (KeyboardInterrupt, Exception) as exc:
            # Typer would turn Ctrl-C into a bare exit code, and Numba into a SystemError; an
            # error after a Ctrl-C that compiled code swallowed is its consequence (Numba caching
            # a function whose compilation the signal cut short).
            if is_interrupt(exc) or interrupt_pending():
                raise Interrupted() from exc
            raise

    def list_commands(self, ctx: typer.Context) -> list[str]:
        return [*super().list_commands(ctx), *_COMMANDS]

    def get_command(self, ctx: typer.Context, cmd_name: str) -> Any:  # a click Command or None
        if cmd_name not in _COMMANDS:
            return super().get_command(ctx, cmd_name)
        module, attribute = _COMMANDS[cmd_name].split(":")
        target = getattr(importlib.import_module(module), attribute)
        if isinstance(target, typer.Typer):
            command = typer.main.get_group(target)
            command.name = cmd_name
        else:
            single = typer.Typer(add_completion=False)  # completion belongs to the root command
            single.command(cmd_name)(target)
            command = typer.main.get_command(single)
        return reflow_help(command)


def paragraphs(text: str) -> str:
    """``text`` (a docstring) with each paragraph on one line: Typer keeps a docstring's line
    breaks in its help, so the source's 100-column lines would show broken mid-sentence at any
    other width. Paragraphs stay apart (blank lines), and so do list items ("- ")."""
    out = []
    for paragraph in inspect.cleandoc(text).split("\n\n"):
        lines: list[str] = []
        for line in paragraph.splitlines():
            if not lines or line.startswith(("- ", "* ")):
                lines.append(line.strip())
            else:
                lines[-1] += " " + line.strip()
        out.append("\n".join(lines))
    return "\n\n".join(out)


def reflow_help(command: Any) -> Any:
    """``command`` (a click Command or Group) with its help and its sub-commands' help as
    :func:`paragraphs`; returns it."""
    if command.help:
        command.help = paragraphs(command.help)
    for sub in getattr(command, "commands", {}).values():
        reflow_help(sub)
    return command


app = typer.Typer(
    cls=_LazyGroup,
    name="spikegyro",
    help="Event camera as a gyroscope: simulate, train, evaluate and run spiking networks.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

_state = {"debug": False}


def _print_version(value: bool) -> None:
    if value:
        typer.echo(__version__)
        raise typer.Exit()


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    version: bool = typer.Option(
        False,
        "--version",
        callback=_print_version,
        is_eager=True,  # before the check that a command was given
        help="Print the version and exit.",
    ),
) -> None:
    _state["debug"] = debug


def _show_warning(message: Any, category: type, *args: Any, **kwargs: Any) -> None:
    if issubclass(category, InputWarning):
        typer.echo(f"warning: {message}", err=True)
    else:
        _default_showwarning(message, category, *args, **kwargs)


_default_showwarning = warnings.showwarning


EXIT_INPUT = 2
EXIT_INTERRUPTED = 130


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _usage_error(exc: Exception) -> int:
    """A usage error (unknown option, value out of range) as one line; its code is kept."""
    if type(exc).__name__ == "NoArgsIsHelpError":  # a bare group: its help is the answer
        exc.show()  # type: ignore[attr-defined]
        return int(exc.exit_code)  # type: ignore[attr-defined]
    ctx = getattr(exc, "ctx", None)
    hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
    typer.echo(f"error: {_one_line(exc.format_message())}{hint}", err=True)  # type: ignore[attr-defined]
    return EXIT_INPUT


def run(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    Only bad input and Ctrl-C are caught here; with ``--debug`` bad input shows its traceback.
    """
    _state["debug"] = False
    warnings.showwarning = _show_warning
    install_sigint_handler()
    try:
        code = app(args=None if argv is None else list(argv), standalone_mode=False)
        check_interrupt()  # a Ctrl-C that compiled code swallowed still means stop
    except InputError as exc:
        if _state["debug"]:
            raise
        typer.echo(f"error: {_one_line(str(exc))}", err=True)
        return EXIT_INPUT
    except (Interrupted, KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted (Ctrl-C); stopped.", err=True)
        return EXIT_INTERRUPTED
    except typer.Exit as exc:
        return exc.exit_code
    except Exception as exc:
        # Recent Typer vendors Click, so its usage errors are not click.ClickException:
        # recognise them by their interface.
        if callable(getattr(exc, "format_message", None)) and isinstance(
            getattr(exc, "exit_code", None), int
        ):
            return _usage_error(exc)
        raise
    # Non-standalone Typer returns the code of a typer.Exit (train's 130) instead of exiting.
    return code if isinstance(code, int) else 0


def main() -> None:
    """Entry point: exit with :func:`run`'s code (return normally on success, so a caller in
    Python goes on)."""
    try:
        code = run()
    except KeyboardInterrupt:  # before or after a command, outside Typer
        typer.echo("interrupted (Ctrl-C); stopped.", err=True)
        code = EXIT_INTERRUPTED
    if code == EXIT_INTERRUPTED:
        # Leave without the interpreter's teardown: after a Ctrl-C that cut Numba's compiler
        # short, LLVM's finalizers can crash it or the signal come back, either of which would
        # replace the exit code. The command's outputs are complete or removed by now.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    if code:
        sys.exit(code)


if __name__ == "__main__":
    main()
