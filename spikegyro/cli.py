"""The ``spikegyro`` command line: one Typer app over every stage of the pipeline.

Each stage keeps its commands in its own ``commands`` module; this file only wires them up and
turns :class:`~spikegyro.errors.InputError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from spikegyro import __version__
from spikegyro.baselines import commands as baselines_commands
from spikegyro.demo import DemoConfig, run_demo
from spikegyro.errors import InputError
from spikegyro.evaluate import commands as evaluate_commands
from spikegyro.evaluate import real as evaluate_real
from spikegyro.events import commands as events_commands
from spikegyro.sim import commands as sim_commands
from spikegyro.stream import commands as stream_commands
from spikegyro.train import commands as train_commands

app = typer.Typer(
    name="spikegyro",
    help="Event camera as a gyroscope: simulate, train, evaluate and run spiking networks.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

_state = {"debug": False}


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    version: bool = typer.Option(False, "--version", help="Print the version and exit."),
) -> None:
    _state["debug"] = debug
    if version:
        typer.echo(__version__)
        raise typer.Exit()


app.command("info")(events_commands.info)
app.command("compare-stats")(events_commands.compare_stats)


@app.command("demo")
def demo(
    out: Path = typer.Option(Path("demo-output"), "--out", help="Output folder."),
    sequences: int = typer.Option(DemoConfig.sequences, min=10, help="Simulated sequences."),
    train_minutes: float = typer.Option(
        DemoConfig.train_minutes, min=0.1, help="Training time budget, minutes."
    ),
    seed: int = typer.Option(DemoConfig.seed, help="Seed of the dataset and the training run."),
) -> None:
    """Simulate a dataset, train SNN-6 on the CPU, evaluate it, and print a summary."""
    run_demo(DemoConfig(out=out, sequences=sequences, train_minutes=train_minutes, seed=seed))


app.command("simulate")(sim_commands.simulate_dataset)
app.command("export-official")(sim_commands.export_official_command)
app.command("show")(sim_commands.show)
app.command("evaluate")(evaluate_commands.evaluate)
app.command("report")(evaluate_commands.report)
app.command("evaluate-real")(evaluate_real.evaluate_real)
app.command("train")(train_commands.train_command)
app.command("predict")(stream_commands.predict)
app.add_typer(baselines_commands.app, name="baseline")


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
    except Exception as exc:  # click usage errors carry their own exit code
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        raise


if __name__ == "__main__":
    main()
