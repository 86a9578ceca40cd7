"""Ctrl-C during training: finish the step, validate and checkpoint, then stop.

A run on a CPU may go for hours between two scheduled checkpoints, so a first Ctrl-C stops it the
way the time budget does (``last.pt`` and ``resume.pt`` written, ``--resume`` continues), and only
a second one aborts at once. The terminal sends Ctrl-C to every process of the group, so data
workers ignore it and leave the decision to the training process.
"""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType, TracebackType


class GracefulStop:
    """While entered (in the main thread), the first SIGINT sets :attr:`requested`."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: signal.Handlers | None = None

    def __enter__(self) -> GracefulStop:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, _signum: int, _frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print(
            "\nCtrl-C: stopping after this step, with a checkpoint (Ctrl-C again aborts).",
            file=sys.stderr,
        )

    def __exit__(
        self,
        _type: type[BaseException] | None,
        _value: BaseException | None,
        _tb: TracebackType | None,
    ) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def ignore_interrupts() -> None:
    """For data-loading workers: Ctrl-C is the training process's to handle."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
