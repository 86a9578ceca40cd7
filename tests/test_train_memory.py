"""The allocator setting of CPU training, against the kernel's own count of page faults."""

from __future__ import annotations

import subprocess
import sys

import pytest

# A fresh process allocates, fills and frees a 256 MB array twice and prints the minor page
# faults of each time (the first must fault: the memory is new to the process; a fault may bring
# in a 4 kB page or a 2 MB transparent huge page).
_SCRIPT = """
import resource, sys
import numpy as np
from spikegyro.train.memory import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
faults = []
for _ in range(2):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = np.empty(64 * 2**20, np.float32)
    block.fill(1.0)
    del block
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(applied, *faults)
"""


def faults(mode: str) -> tuple[str, int, int]:
    """(whether the setting applied, faults of the first pass, of the second)."""
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT, mode], capture_output=True, text=True, check=True
    )
    applied, first, second = done.stdout.split()
    return applied, int(first), int(second)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator: Linux")
def test_a_freed_block_is_reused_without_faulting_its_pages_in_again():
    """Without the setting glibc maps a 256 MB block anew each time (a fault per 4 kB page); with
    it the second block reuses the first one's pages."""
    applied, first, kept = faults("keep")
    if applied != "True":
        pytest.skip("the C library is not glibc")
    _, first_default, default = faults("default")
    assert first > 100 and first_default > 100  # at least 256 MB / 2 MB pages
    assert default > 0.5 * first_default
    assert kept < 0.02 * first
