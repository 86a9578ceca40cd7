"""Checks that every command runs on its options before it reads much or writes anything.

Each raises :class:`~spikegyro.errors.InputError` with a message naming the option, the value and
the fix, so a bad output path or device is refused before hours of work, not after.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from spikegyro.errors import InputError


def _check_parent(path: Path, option: str) -> None:
    """The nearest existing ancestor must be a writable folder (missing ones get created)."""
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{option} {path}: {parent} is a file, not a folder; choose another path.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{option} {path}: cannot write in {parent}; choose a writable folder.")


def check_output_file(
    path: str | os.PathLike, option: str = "--out", suffixes: Iterable[str] | None = None
) -> Path:
    """``path`` may be written as a file: not a folder, in a writable place, with one of
    ``suffixes`` (lower case, with the dot) when given. An existing file is replaced."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; give a file name instead.")
    if suffixes is not None:
        allowed = tuple(suffixes)
        if path.suffix.lower() not in allowed:
            raise InputError(
                f"{option} {path}: unknown format '{path.suffix}'; use {_or(allowed)}."
            )
    _check_parent(path, option)
    return path


def check_output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` may be used as an output folder: a folder or nothing yet, in a writable place."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path}: is a file, not a folder; give a folder name instead.")
    _check_parent(path / "_", option)
    return path


def check_input(path: str | os.PathLike, option: str, *, folder: bool = False) -> Path:
    """``path`` must exist (as a folder when ``folder``, else as a file)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{option} {path}: no such {'folder' if folder else 'file'}.")
    if folder and not path.is_dir():
        raise InputError(f"{option} {path}: is a file; give a folder.")
    if not folder and path.is_dir():
        raise InputError(f"{option} {path}: is a folder; give a file.")
    return path


def check_device(name: str | None, option: str = "--device") -> str | None:
    """A torch device name the machine has (``auto``/None pass through); checked before torch
    is asked, so a typo is one line instead of a traceback deep in a run."""
    if name is None or name == "auto":
        return name
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise InputError(
            f"{option} {name}: not a device; use cpu, cuda or cuda:K (K a GPU index)."
        ) from None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if (device.index or 0) >= count:
            raise InputError(
                f"{option} {name}: this machine has {count} CUDA device(s); use cpu"
                + (f" or cuda:0..{count - 1}." if count else ".")
            )
    elif device.type != "cpu":
        raise InputError(f"{option} {name}: unsupported device type; use cpu or cuda.")
    return name


def _or(items: tuple[str, ...]) -> str:
    return ", ".join(items[:-1]) + f" or {items[-1]}" if len(items) > 1 else items[0]


def sensor_option(width: int | None, height: int | None) -> tuple[int, int] | None:
    """``--width``/``--height`` as a sensor size: both or neither, each at least one pixel."""
    if width is None and height is None:
        return None
    if width is None or height is None:
        raise InputError("--width and --height go together; give both (pixels) or neither.")
    if width < 1 or height < 1:
        raise InputError(f"--width {width} --height {height}: a sensor is at least 1x1 pixels.")
    return int(width), int(height)


FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".eps", ".ps")
"""What matplotlib writes, by extension."""
