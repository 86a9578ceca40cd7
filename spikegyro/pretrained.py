"""Bundled weights, by name: ``spikegyro/data/pretrained/<name>.pt`` with its model card
``<name>.md`` (and, where it has them, the training log, curve and configuration in the folder
``<name>/``).

Every command that takes a checkpoint (``--checkpoint``, ``train --init``, ``export-nir``) takes
either a bundled name (``snn6``, ``ann6``, …) or a path. A bundled name wins over a file of the
same name in the working folder; write ``./snn6`` for that file. Torch-free, so that
``spikegyro predict`` resolves its checkpoint without importing torch;
:mod:`spikegyro.models.registry` re-exports these functions.
"""

from __future__ import annotations

import os
from pathlib import Path

from spikegyro.errors import InputError

PRETRAINED_DIR = Path(__file__).resolve().parent / "data" / "pretrained"
"""Where the bundled weights and their model cards live."""

DEFAULT_NAME = "snn6"
"""The bundled model that ``predict``, ``evaluate`` and ``demo`` use when none is given."""


def bundled_names() -> list[str]:
    """Names of the bundled weights (``<name>.pt`` in :data:`PRETRAINED_DIR`), sorted."""
    return sorted(path.stem for path in PRETRAINED_DIR.glob("*.pt"))


def bundled_path(name: str) -> Path:
    """The file of bundled weights ``name`` (which need not exist: see :func:`bundled_names`)."""
    return PRETRAINED_DIR / f"{name}.pt"


def model_card(name: str) -> Path:
    """The model card (Markdown) of bundled weights ``name``."""
    return PRETRAINED_DIR / f"{name}.md"


def _looks_like_name(spec: str) -> bool:
    """A bare word (no folder, no suffix) is meant as a bundled name, not as a file."""
    return os.sep not in spec and "/" not in spec and not Path(spec).suffix


def resolve_checkpoint(spec: str | os.PathLike, option: str = "--checkpoint") -> Path:
    """The checkpoint file that ``spec`` names: bundled weights by name, else a path.

    Args:
        spec: a bundled name (see :func:`bundled_names`) or the path of a checkpoint file.
        option: the command-line option named in the error message.

    Raises:
        InputError: one line when ``spec`` is neither a bundled name nor an existing file,
            listing the bundled names.
    """
    text = os.fspath(spec)
    names = bundled_names()
    if text in names:
        return bundled_path(text)
    path = Path(text)
    if path.is_file():
        return path
    if path.is_dir():
        what = "is a folder, not a checkpoint file"
    elif _looks_like_name(text):
        what = "not a bundled model and no such checkpoint file"
    else:
        what = "no such checkpoint file"
    valid = ", ".join(names) or "none installed"
    raise InputError(f"{option} {text}: {what}; give a checkpoint file or one of: {valid}.")


def checkpoint_help(what: str = "Checkpoint", default: str | None = DEFAULT_NAME) -> str:
    """Help text of an option that takes a checkpoint: a file or a bundled name."""
    tail = f"; default {default}" if default else ""
    return f"{what}: a file or the name of bundled weights ({', '.join(bundled_names())}{tail})."
