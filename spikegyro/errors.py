"""The exception types that the command line turns into one line, and how it recognises Ctrl-C."""

from __future__ import annotations

import signal
import sys
import threading
from typing import Any


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


class _Sigint:
    pending = False


def install_sigint_handler() -> None:
    """Make Ctrl-C sticky for this process (main thread only, and only where SIGINT still has
    Python's default handler, so a run started with SIGINT ignored keeps ignoring it).

    The first Ctrl-C raises :class:`KeyboardInterrupt` as usual, and is also remembered: code
    called back from compiled libraries (Numba's JIT writing its cache through llvmlite) can
    swallow the exception, and :func:`check_interrupt` then raises it again at the next safe
    point of a long loop.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return
    _Sigint.pending = False

    def handler(signum: int, frame: object) -> None:
        _Sigint.pending = True
        raise KeyboardInterrupt

    def unraisable(hook_args: Any) -> None:
        # the swallowed Ctrl-C would print a traceback; check_interrupt reports it instead
        if not isinstance(hook_args.exc_value, KeyboardInterrupt):
            sys.__unraisablehook__(hook_args)

    signal.signal(signal.SIGINT, handler)
    sys.unraisablehook = unraisable


def check_interrupt() -> None:
    """Raise :class:`KeyboardInterrupt` if Ctrl-C came and was swallowed since the handler was
    installed; long loops call this once per block."""
    if _Sigint.pending:
        raise KeyboardInterrupt


def interrupt_pending() -> bool:
    """Whether Ctrl-C came since :func:`install_sigint_handler` (even if it was swallowed)."""
    return _Sigint.pending
