"""The ``spikegyro`` command line: one Typer app over every stage of the pipeline.

Each stage keeps its commands in its own ``commands`` module; this file only wires them up and
turns :class:`~spikegyro.errors.InputError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

import typer
from typer.core import TyperGroup

from spikegyro import __version__
from spikegyro.errors import InputError

_COMMANDS: dict[str, str] = {
    "info": "spikegyro.events.commands:info",
    "convert": "spikegyro.events.commands:convert_command",
    "compare-stats": "spikegyro.events.commands:compare_stats",
    "demo": "spikegyro.demo:demo_command",
    "simulate": "spikegyro.sim.commands:simulate_dataset",
    "export-official": "spikegyro.sim.commands:export_official_command",
    "show": "spikegyro.sim.commands:show",
    "evaluate": "spikegyro.evaluate.commands:evaluate",
    "evaluate-real": "spikegyro.evaluate.real:evaluate_real",
    "report": "spikegyro.evaluate.commands:report",
    "export-nir": "spikegyro.models.commands:export_nir_command",
    "train": "spikegyro.train.commands:train_command",
    "relay-log": "spikegyro.train.relay:relay_log_command",
    "predict": "spikegyro.stream.commands:predict",
    "baseline": "spikegyro.baselines.commands:app",
}
"""Command name -> ``module:attribute`` (a command function or a Typer sub-app). A stage's module
is imported only when its command runs or ``--help`` lists it, so ``spikegyro predict`` does not
pay for torch or matplotlib."""


class _LazyGroup(TyperGroup):
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
            return command
        single = typer.Typer()
        single.command(cmd_name)(target)
        return typer.main.get_command(single)


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


def main() -> None:
    """Entry point: run the app, printing user errors as one line (exit 2)."""
    try:
        app(standalone_mode=False)
    except InputError as exc:
        if _state["debug"]:
            raise
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except Exception as exc:
        # Usage errors carry their own message and exit code. Recent Typer vendors Click, so
        # its exceptions are not click.ClickException: recognise them by their interface.
        show, code = getattr(exc, "show", None), getattr(exc, "exit_code", None)
        if callable(show) and isinstance(code, int):
            show()
            sys.exit(code)
        raise


if __name__ == "__main__":
    main()
