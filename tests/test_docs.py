"""The documentation and the files a published package carries: no reference dangles.

`make docs` builds the site with warnings as errors (broken links inside docs/ included); these
tests cover what MkDocs cannot see: references from the code, the tests, the scripts and the
top-level Markdown files to docs pages, scripts and benchmarks.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
import tomllib
import yaml

from spikegyro.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [
    *sorted((ROOT / "spikegyro").rglob("*.py")),
    *sorted((ROOT / "spikegyro").rglob("*.md")),
    *sorted((ROOT / "tests").glob("*.py")),
    *sorted((ROOT / "bench").glob("*.py")),
    *sorted((ROOT / "scripts").rglob("*.*")),
    *sorted((ROOT / "runs").rglob("*.md")),
    *sorted((ROOT / "docs").rglob("*.md")),
    ROOT / "README.md",
    ROOT / "BENCHMARKS.md",
    ROOT / "CHANGELOG.md",
    ROOT / "Makefile",
]
# A path inside the repository as the text names it: docs/x.md, scripts/.../x.sh, bench/x.py.
REFERENCE = re.compile(r"(?<![\w/.-])((?:docs|scripts|bench|runs)/[\w./-]*\w)")


def _texts() -> list[tuple[Path, str]]:
    return [(p, p.read_text(errors="replace")) for p in SOURCES if p.is_file()]


def test_no_reference_to_the_retired_design_notes() -> None:
    retired = ("DESIGN" + ".md", "docs/" + "notes")
    found = [
        f"{path.relative_to(ROOT)}:{n}"
        for path, text in _texts()
        if path != Path(__file__).resolve()
        for n, line in enumerate(text.splitlines(), 1)
        if any(word in line for word in retired)
    ]
    assert not found, f"references to retired notes (point at a docs/ page instead): {found}"


def test_every_referenced_repository_path_exists() -> None:
    missing = []
    for path, text in _texts():
        if path == Path(__file__).resolve():
            continue
        for match in REFERENCE.finditer(text):
            ref = match.group(1).rstrip(".")
            if "*" in ref or ref.endswith("/"):
                continue
            # Links inside docs/ pages are relative to the page; MkDocs checks those.
            if path.is_relative_to(ROOT / "docs") and not ref.startswith(("scripts/", "bench/")):
                continue
            if ref.startswith("runs/") and not (ROOT / "runs" / ref.split("/")[1]).is_dir():
                continue  # a user's own run (train's default --out is runs/train-MODEL-TIME)
            if not (ROOT / ref).exists():
                missing.append(f"{path.relative_to(ROOT)}: {ref}")
    assert not missing, f"references to files that do not exist: {missing}"


def test_the_reference_pattern_finds_paths() -> None:
    text = "see docs/snn.md, `scripts/train_segments.sh OUT` and bench/snn_step.py."
    assert [m.group(1) for m in REFERENCE.finditer(text)] == [
        "docs/snn.md",
        "scripts/train_segments.sh",
        "bench/snn_step.py",
    ]


def test_every_docs_page_is_in_the_navigation_and_every_api_module_exists() -> None:
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())

    def pages(node: object) -> list[str]:
        if isinstance(node, str):
            return [node]
        if isinstance(node, list):
            return [p for item in node for p in pages(item)]
        if isinstance(node, dict):
            return [p for value in node.values() for p in pages(value)]
        return []

    nav = set(pages(config["nav"]))
    on_disk = {str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")}
    assert nav == on_disk
    for page in (ROOT / "docs" / "api").glob("*.md"):
        for module in re.findall(r"^::: ([\w.]+)", page.read_text(), re.MULTILINE):
            parts = module.split(".")
            as_file = ROOT.joinpath(*parts).with_suffix(".py")
            as_package = ROOT.joinpath(*parts, "__init__.py")
            assert as_file.exists() or as_package.exists(), f"{page.name}: {module}"


def test_package_metadata_license_and_citation_agree() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert "dask[distributed]>=2024.1" not in project["dependencies"]
    assert any(
        d.startswith("dask[distributed]") for d in project["optional-dependencies"]["distributed"]
    )
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    assert str(cff["version"]) == project["version"]
    paper = cff["preferred-citation"]
    assert paper["doi"] == "10.1109/ICRA40945.2020.9197133"
    assert [a["family-names"] for a in paper["authors"]] == [
        "Gehrig", "Shrestha", "Mouritzen", "Scaramuzza"
    ]  # fmt: skip
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in changelog
    assert f"## [{project['version']}]" in changelog


def test_scheduler_without_dask_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from spikegyro.sim.dataset import generate_dataset

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(InputError, match=r"pip install 'spikegyro\[distributed\]'"):
        generate_dataset(tmp_path / "data", 3, scheduler="tcp://127.0.0.1:8786")
    assert not (tmp_path / "data").exists()  # refused before anything is written


TOP_LEVEL_DOCS = (ROOT / "README.md", ROOT / "BENCHMARKS.md")
# Tracker references: "issue 20", "issues 19, 20", "#31" (a heading's "#" is followed by a space).
ISSUE_REFERENCE = re.compile(r"\bissues? \d+|(?<![\w&])#\d+\b", re.IGNORECASE)


def _readme_command_lines() -> list[str]:
    """Every ``spikegyro ...`` invocation in README.md's code blocks, continuation lines joined."""
    blocks, block, language = [], None, ""
    for line in (ROOT / "README.md").read_text().splitlines():
        if line.startswith("```"):
            if block is None:
                block, language = [], line[3:].strip()
            else:
                if language in ("", "bash", "sh", "console"):
                    blocks.append("\n".join(block))
                block = None
        elif block is not None:
            block.append(line)
    lines = []
    for text in blocks:
        for line in text.replace("\\\n", " ").splitlines():
            line = line.split("#", 1)[0].strip()  # drop shell comments
            if line.startswith("spikegyro "):
                lines.append(line)
    return lines


def test_readme_and_benchmarks_name_no_tracker_issues_or_retired_notes() -> None:
    for path in TOP_LEVEL_DOCS:
        text = path.read_text()
        found = [
            f"{path.name}:{n}: {m.group(0)}"
            for n, line in enumerate(text.splitlines(), 1)
            for m in ISSUE_REFERENCE.finditer(line)
        ]
        assert not found, f"issue numbers in a user document: {found}"
        assert "DESIGN" + ".md" not in text, path.name


def test_issue_reference_pattern() -> None:
    assert ISSUE_REFERENCE.search("as issue 20 asks") and ISSUE_REFERENCE.search("(issues 19, 20)")
    assert ISSUE_REFERENCE.search("fixed in #31")
    assert not ISSUE_REFERENCE.search("## Heading")
    assert not ISSUE_REFERENCE.search("snnTorch issues ~30 small ops")


def test_every_command_in_the_readme_exists_with_the_options_it_names() -> None:
    import typer

    from spikegyro.cli import _COMMANDS, app

    lines = _readme_command_lines()
    assert len(lines) >= 10, lines
    group = typer.main.get_command(app)
    ctx = group.make_context("spikegyro", ["--help"], resilient_parsing=True)
    for line in lines:
        words = line.split()[1:]
        while words and words[0].startswith("--"):  # global options such as --debug
            words.pop(0)
        assert words and words[0] in _COMMANDS, f"README: not a spikegyro command: {line}"
        command = group.get_command(ctx, words[0])
        if hasattr(command, "commands"):  # a sub-app: `spikegyro baseline cmax`
            command = command.commands[words[1]]
        options = {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)}
        named = {w.split("=", 1)[0] for w in words if w.startswith("-") and not w[1:2].isdigit()}
        assert named <= options, f"README: {line}: unknown options {sorted(named - options)}"
