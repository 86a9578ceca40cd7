"""The one exception type that the command line turns into a one-line message."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a missing file, a wrong layout, invalid events, a mismatched checkpoint.

    The message is a complete sentence that names the offending file or value and says how to
    fix it; the command line prints it on one line and exits with code 2.
    """


class InputWarning(UserWarning):
    """A problem in the input that a reader worked around (a truncated file's partial last
    record, a sensor size guessed from the events, a non-conformant encoding read as its writer
    meant). The message is one sentence naming the file; the command line prints it on one line.
    """
