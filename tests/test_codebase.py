"""The package stays easy to pick up: no function longer than a screen, and every command in a
stage's ``commands.py``.

Functions still waiting to be split are listed in ``PENDING`` with their length when they were
listed: the test fails when one of them grows, and when one is split (then its entry goes), so
the list only shrinks.
"""

from __future__ import annotations

import ast
from pathlib import Path

from spikegyro.cli import _COMMANDS

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "spikegyro"
MAX_FUNCTION_LINES = 80
"""Longest function, in lines from ``def`` (decorators excluded) to its last line."""

PENDING: dict[tuple[str, str], int] = {}
"""(file, function) -> its length in lines when listed; every entry is over the limit."""

PENDING_COMMANDS: dict[str, str] = {}
"""Command name -> target of the commands not yet in a ``commands`` module."""


def _function_lengths() -> dict[tuple[str, str], int]:
    """(file relative to the repository, qualified function name) -> lines, for every function
    and method in the package (nested ones under their parent's name)."""
    lengths = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        file = path.relative_to(ROOT).as_posix()

        def visit(node: ast.AST, prefix: str, file: str = file) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                    name = f"{prefix}{child.name}"
                    if not isinstance(child, ast.ClassDef):
                        lengths[(file, name)] = child.end_lineno - child.lineno + 1
                    visit(child, f"{name}.")
                else:
                    visit(child, prefix)

        visit(ast.parse(path.read_text(encoding="utf-8")), "")
    return lengths


def test_no_function_is_longer_than_the_limit():
    lengths = _function_lengths()
    too_long = {
        key: n for key, n in lengths.items() if n > MAX_FUNCTION_LINES and key not in PENDING
    }
    assert not too_long, (
        f"functions over {MAX_FUNCTION_LINES} lines (split them into named steps): {too_long}"
    )


def test_pending_long_functions_only_shrink():
    lengths = _function_lengths()
    missing = [key for key in PENDING if key not in lengths]
    assert not missing, f"PENDING names functions that no longer exist (drop them): {missing}"
    done = [key for key in PENDING if lengths[key] <= MAX_FUNCTION_LINES]
    assert not done, f"now within {MAX_FUNCTION_LINES} lines: drop them from PENDING: {done}"
    grown = {key: (PENDING[key], lengths[key]) for key in PENDING if lengths[key] > PENDING[key]}
    assert not grown, f"PENDING functions grew (listed, now): split them instead: {grown}"


def test_every_command_lives_in_a_commands_module():
    elsewhere = {
        name: target
        for name, target in _COMMANDS.items()
        if target.split(":")[0].rsplit(".", 1)[-1] != "commands" and name not in PENDING_COMMANDS
    }
    assert not elsewhere, f"commands outside a stage's commands.py: {elsewhere}"
    moved = [n for n, t in PENDING_COMMANDS.items() if _COMMANDS.get(n) != t]
    assert not moved, f"PENDING_COMMANDS entries that moved or went (drop them): {moved}"


def test_every_command_target_exists():
    import importlib

    for name, target in _COMMANDS.items():
        module, attribute = target.split(":")
        assert hasattr(importlib.import_module(module), attribute), name
