"""The old homes of contrast maximization, kept for one release: importing one warns and
forwards every name to its new module in :mod:`spikegyro.cmax`."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any


def forward(old: str, *new: str) -> Callable[[str], Any]:
    """Warn that module ``old`` moved to the modules ``new``; returns the module
    ``__getattr__`` that looks a name up in them, in order."""
    warnings.warn(
        f"{old} is deprecated and will be removed in the next release; "
        f"import from {' or '.join(new)} instead",
        DeprecationWarning,
        stacklevel=3,
    )
    modules = [importlib.import_module(name) for name in new]

    def getattr_(name: str) -> Any:
        for module in modules:
            if hasattr(module, name):
                return getattr(module, name)
        raise AttributeError(f"module {old!r} has no attribute {name!r}")

    return getattr_
