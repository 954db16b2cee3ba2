"""glibc's malloc told to keep freed tensor memory for reuse instead of handing it back.

Rendering makes many short-lived tensors of a few MB (a chunk of 128 contacts at 128 x 128
is 8 MB a map). glibc returns such blocks to the kernel when they are freed (``munmap``, or
trimming the top of the heap), so the next tensor of that size faults in fresh zeroed
pages, paid in system time. Fixing the mmap threshold at 32 MiB (where glibc's own adaptive
threshold stops) and the trim threshold at ``TRIM_THRESHOLD`` keeps those pages in the
process for the next tensor (the faults and times it saves: docs/results/code_figures.md).

The command line (``tactile_bench.cli.main``) and the corpus builder's worker processes set
it: they own their processes. Importing the package changes nothing. Elsewhere than glibc
(macOS, musl) there is nothing to set and :func:`keep_freed_memory` returns False.
"""

from __future__ import annotations

import ctypes
import functools

#: ``mallopt`` parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: blocks at least this big still get their own mapping: where glibc's adaptive threshold
#: stops by default (4 * 1024 * 1024 * sizeof(long))
MMAP_THRESHOLD = 32 << 20
#: free memory at the top of a heap beyond this is returned to the kernel: a few chunks'
#: worth of maps, so a render's working set stays mapped while a fit's large frees still go
TRIM_THRESHOLD = 128 << 20

_set_here = False  # keep_freed_memory() succeeded in this process


@functools.cache
def glibc() -> ctypes.CDLL | None:
    """The C library this process runs on, if it is glibc (the only one with ``mallopt``'s
    thresholds as used here)."""
    try:
        libc = ctypes.CDLL(None)
    except OSError:  # Windows: no process-wide symbol table to open
        return None
    is_glibc = hasattr(libc, "gnu_get_libc_version") and hasattr(libc, "mallopt")
    return libc if is_glibc else None


def keep_freed_memory() -> bool:
    """Set this process's malloc thresholds (see the module's docstring); False if not glibc.

    Process-wide and one-way (glibc has no call that restores its dynamic thresholds), so
    only code that owns the process calls it. Calling it again changes nothing.
    """
    global _set_here
    libc = glibc()
    if libc is None:
        return False
    ok = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    _set_here = libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1 and ok
    return _set_here


def describe() -> str:
    """What this process's malloc does with freed memory, for benchmark reports."""
    if not _set_here:
        return "default"
    mmap, trim = MMAP_THRESHOLD >> 20, TRIM_THRESHOLD >> 20
    return f"glibc, mmap threshold {mmap} MiB, trim threshold {trim} MiB"
