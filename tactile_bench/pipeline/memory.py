"""Each stage's peak memory: the kernel's high-water mark of this process, reset per stage.

A whole run's peak (``/usr/bin/time -v``) does not say which stage reached it. Linux keeps a
resident-set high-water mark per process (``VmHWM`` in ``/proc/self/status``) that writing
``5`` to ``/proc/self/clear_refs`` resets (proc(5)), so the runner resets it before a stage
and reads it after. Elsewhere both calls do nothing and the peak is None. Worker processes a
stage spawns (``parallel_seeds``) are not counted: each has its own mark.
"""

from __future__ import annotations

from contextlib import suppress
from pathlib import Path

_CLEAR_REFS = Path("/proc/self/clear_refs")
_STATUS = Path("/proc/self/status")


def reset_peak_rss() -> None:
    """Start a new high-water mark at the current resident set size (Linux only)."""
    with suppress(OSError):
        _CLEAR_REFS.write_text("5")


def peak_rss_mib() -> float | None:
    """The resident-set high-water mark since the last reset, in MiB (None off Linux)."""
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # the kernel reports kB
    except (OSError, ValueError, IndexError):
        return None
    return None
