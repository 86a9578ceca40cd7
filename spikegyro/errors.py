"""The one exception type that the command line turns into a one-line message."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a missing file, a wrong layout, invalid events, a mismatched checkpoint.

    The message is a complete sentence that names the offending file or value and says how to
    fix it; the command line prints it on one line and exits with code 2.
    """
