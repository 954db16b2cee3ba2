"""Each stage's peak memory: reset per stage, so a small stage after a big one reads small."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from tactile_bench.pipeline.memory import peak_rss_mib, reset_peak_rss

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux")


@linux_only
def test_the_peak_falls_after_a_reset_and_rises_with_an_allocation() -> None:
    reset_peak_rss()
    before = peak_rss_mib()
    block = np.ones(200 * 2**20 // 8)  # 200 MiB, touched
    during = peak_rss_mib()
    del block
    after_free = peak_rss_mib()
    reset_peak_rss()
    after_reset = peak_rss_mib()
    assert before is not None and during is not None and after_free is not None
    assert after_reset is not None
    assert during - before > 150  # the allocation is seen
    # a high-water mark: freeing does not lower it (the kernel syncs its per-thread RSS
    # counters lazily, so the mark may read a few pages off)
    assert after_free > during - 8
    assert after_reset < during - 150  # the reset does
