"""The demo: events in, angular velocity out, with the shipped SNN-6, on a CPU.

:func:`run_demo` runs it (:mod:`.pipeline` says what it does and writes); ``spikegyro demo`` is
its command (:mod:`.commands`).
"""

from spikegyro.demo.pipeline import DemoConfig, run_demo

__all__ = ["DemoConfig", "run_demo"]
