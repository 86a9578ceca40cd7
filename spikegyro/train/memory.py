"""How the C allocator treats the large blocks of a training step on a CPU.

A training step allocates its activations anew every step: SNN-6's dense path about 2.2 GB for a
batch of 8 windows at 240x180. glibc's malloc serves a block above its mmap threshold (32 MB at
most) from a mapping of its own and unmaps it when it is freed, so every step the kernel maps and
zeroes those pages again: 30-40 % of the dense path's CPU time on a 2-core VM, and a wall time
that moves with the host's memory state. Told to serve every block from its heap and to keep what
is freed, malloc reuses the same pages from step to step.
"""

from __future__ import annotations

import ctypes
import sys

_M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
_M_MMAP_MAX = -4
_NEVER_TRIM = -1  # mallopt(3): a trim threshold of -1 disables trimming (2 GB would not)


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory for reuse, for the rest of the process: no block
    from a mapping of its own (M_MMAP_MAX = 0; malloc still maps memory when its heap cannot
    grow) and no trimming of the heap (M_TRIM_THRESHOLD = −1). The resident memory then
    stays at the largest step's, instead of being mapped again every step.

    Returns whether it applied: False where the C library is not glibc (macOS, Windows, musl),
    which keep their own policies.
    """
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None)  # the C library this process already runs on
    if not hasattr(libc, "gnu_get_libc_version"):
        return False
    return bool(libc.mallopt(_M_MMAP_MAX, 0)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, _NEVER_TRIM))
