"""The exception types that the command line turns into one line, and how it recognises Ctrl-C."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a missing file, a wrong layout, invalid events, a mismatched checkpoint.

    The message is a complete sentence that names the offending file or value and says how to
    fix it; the command line prints it on one line and exits with code 2.
    """


class Interrupted(Exception):
    """Ctrl-C stopped a command; the command line exits with code 130.

    Deliberately not a :class:`KeyboardInterrupt`: the command line framework would otherwise
    swallow it into a bare exit code before a message can be printed.
    """


def is_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is Ctrl-C, directly or wrapped: compiled (Numba) code that a SIGINT
    interrupts re-raises the pending :class:`KeyboardInterrupt` as a ``SystemError`` whose cause
    or context it is."""
    if isinstance(exc, (KeyboardInterrupt, Interrupted)):
        return True
    if not isinstance(exc, SystemError):
        return False
    cause = exc.__cause__ or exc.__context__
    return cause is not None and cause is not exc and is_interrupt(cause)


class InputWarning(UserWarning):
    """A problem in the input that a reader worked around (a truncated file's partial last
    record, a sensor size guessed from the events, a non-conformant encoding read as its writer
    meant). The message is one sentence naming the file; the command line prints it on one line.
    """
