"""The run's peak memory at the end of each stage: the stage that raised it reached it.

A whole run's peak (``/usr/bin/time -v``) does not say which stage reached it. The process's
resident-set high-water mark (``ru_maxrss``) never comes down, so the runner reads it after
every stage: the stage after which it rose is the one that set the new peak, and the last
stage's figure is the run's peak. (Linux can reset the mark through /proc/self/clear_refs,
but that would also hide the run's true peak from ``/usr/bin/time``, so it is not done.)
Worker processes a stage spawns (``parallel_seeds``) have marks of their own, not counted.
A stage run side by side (``jobs`` > 1) reads the mark of its worker process, which ran
the worker's earlier stages too.
"""

from __future__ import annotations

import resource
import sys


def peak_rss_mib() -> float:
    """This process's resident-set high-water mark so far, in MiB."""
    scale = 1 if sys.platform == "darwin" else 1024  # macOS reports bytes, Linux KiB
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale / 2**20
