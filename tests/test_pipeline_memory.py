"""The run's peak memory: a high-water mark that an allocation raises and freeing keeps."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from tactile_bench.pipeline.memory import peak_rss_mib

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def rss_mib() -> float:
    """The resident set size now (not the peak), from /proc/self/statm."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def allocate_above_peak(extra_mib: float) -> np.ndarray:
    """A touched array that lifts the resident set ``extra_mib`` above the peak so far."""
    mib = max(0.0, peak_rss_mib() - rss_mib()) + extra_mib if extra_mib > 0 else 0.0
    return np.ones(max(1, int(mib * 2**20) // 8))


def test_an_allocation_above_the_peak_raises_it_and_freeing_keeps_it() -> None:
    before = peak_rss_mib()
    block = allocate_above_peak(200)
    during = peak_rss_mib()
    del block
    assert during - before > 150
    assert peak_rss_mib() >= during
