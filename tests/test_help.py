"""Every command's ``--help`` reads as paragraphs at 80 and 120 columns: the docstrings' source
line breaks do not survive into the rendered help."""

from __future__ import annotations

import itertools

import pytest
from typer.testing import CliRunner

from spikegyro.cli import _COMMANDS, app, paragraphs

WIDTHS = (80, 120)


def _command_paths() -> list[list[str]]:
    """Every command and every sub-command of a group, as the words that name it."""
    from spikegyro.cli import _LazyGroup

    group = _LazyGroup()
    paths = []
    for name in _COMMANDS:
        command = group.get_command(None, name)  # type: ignore[arg-type]
        paths.append([name])
        # Typer vendors its own click, so a group is known by its sub-commands, not its class.
        paths += [[name, sub] for sub in getattr(command, "commands", {})]
    return paths


def _description(output: str) -> list[str]:
    """The help's prose: the lines between the usage line and the first box, stripped."""
    lines = output.splitlines()
    start = next(i for i, line in enumerate(lines) if "Usage:" in line) + 1
    prose = []
    for line in lines[start:]:
        if line.lstrip().startswith("╭"):
            break
        prose.append(line.strip())
    return prose


def broken_lines(prose: list[str], width: int) -> list[str]:
    """Lines of ``prose`` (rendered with one column of margin each side) that end although the
    next line's first word would have fitted: a line break that the wrapping did not make.
    A blank line (a paragraph's end) or a list item ("- ") may follow a short line."""
    room = width - 2
    return [
        line
        for line, after in itertools.pairwise(prose)
        if line and after and not after.startswith(("- ", "* "))
        and len(line) + 1 + len(after.split()[0]) <= room
    ]  # fmt: skip


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("path", _command_paths(), ids=" ".join)
def test_help_wraps_paragraphs_at_the_terminal_width(path: list[str], width: int) -> None:
    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": str(width)})
    assert result.exit_code == 0, result.output
    prose = _description(result.output)
    assert any(prose), f"{' '.join(path)}: no description"
    assert max(len(line) for line in prose) <= width - 2
    assert not broken_lines(prose, width), f"{' '.join(path)} --help at {width} columns"


def test_the_check_finds_a_source_line_break_left_in_a_paragraph() -> None:
    source = "first words of a sentence\nthat goes on.\n\nA second paragraph."
    assert broken_lines(source.splitlines(), 80) == ["first words of a sentence"]
    assert not broken_lines(paragraphs(source).splitlines(), 80)


def test_paragraphs_keep_blank_lines_and_list_items() -> None:
    text = """One line
    and its continuation.

    - an item
      that wraps
    - another"""
    assert paragraphs(text) == (
        "One line and its continuation.\n\n- an item that wraps\n- another"
    )
