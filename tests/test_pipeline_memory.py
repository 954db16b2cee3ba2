"""The run's peak memory: a high-water mark that an allocation raises and freeing keeps.

The allocation runs in a fresh interpreter, whose peak is only its imports. In the test
session the peak already holds torch and every earlier test (1.26 GiB), and there CI once saw
a block lifted 200 MiB above it leave the mark unmoved (before == during); not reproduced on
our machine and not isolated (reclaim of the mapped libraries' pages is one candidate, so
the stage tests' ``allocate_above_peak`` keeps adding blocks until the mark moves).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from tactile_bench.pipeline.memory import peak_rss_mib

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

_ALLOCATE = """
import json, os, numpy as np
from tactile_bench.pipeline.memory import peak_rss_mib
with open("/proc/self/statm") as f:
    resident = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
before = peak_rss_mib()
# the block lifts the resident set 200 MiB above the peak the imports left behind
block = np.ones(int((before - resident + 200) * 2**20) // 8)  # every page written
during = peak_rss_mib()
del block
print(json.dumps([before, during, peak_rss_mib()]))
"""


def rss_mib() -> float:
    """The resident set size now (not the peak), from /proc/self/statm."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def allocate_above_peak(extra_mib: float, chunk_mib: int = 16) -> list[np.ndarray]:
    """Touched blocks that lift this process's peak RSS by ``extra_mib`` (for stage tests).

    Blocks are added until the mark has moved, at most four times ``extra_mib`` beyond the
    gap between the resident set and the peak: while they are touched the kernel may drop
    pages of the mapped libraries, so the resident set can need more than that gap.
    """
    if extra_mib <= 0:
        return [np.ones(1)]
    target = peak_rss_mib() + extra_mib
    limit = max(0.0, peak_rss_mib() - rss_mib()) + 4 * extra_mib
    blocks: list[np.ndarray] = []
    while peak_rss_mib() < target and chunk_mib * len(blocks) < limit:
        blocks.append(np.ones(chunk_mib * 2**20 // 8))
    return blocks


def vm_hwm_mib() -> float:
    """The kernel's own high-water mark (VmHWM in /proc/self/status), in MiB."""
    with open("/proc/self/status") as f:
        line = next(row for row in f if row.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024


def test_the_peak_is_the_kernels_high_water_mark_in_mib() -> None:
    assert abs(peak_rss_mib() - vm_hwm_mib()) < 16


def test_an_allocation_above_the_peak_raises_it_and_freeing_keeps_it() -> None:
    out = subprocess.run(
        [sys.executable, "-c", _ALLOCATE], capture_output=True, text=True, check=True
    )
    before, during, after = json.loads(out.stdout)
    assert during - before > 150
    assert after >= during
