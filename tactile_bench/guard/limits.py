"""Bounds on sizes and counts, checked against what they would allocate.

A size that would need more memory (or disk) than the machine has is refused before any
work with the estimate and the limit in the message, instead of growing until the
allocator fails (or the kernel kills the process) and leaving a half-built folder.
"""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from tactile_bench.errors import TactileBenchError

#: environment variable overriding the memory limit, e.g. ``8G`` or ``500M``
MEMORY_LIMIT_ENV = "TACTILE_BENCH_MEMORY_LIMIT"
#: the share of the machine's memory one command may plan to use
MEMORY_SHARE = 0.75
#: seeds are 32-bit (numpy's SeedSequence, torch.Generator.manual_seed and DataLoader
#: workers all accept them); negative seeds are refused rather than mapped
SEED_MAX = 2**32 - 1
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def format_bytes(n: float) -> str:
    """``3.2 GiB``: a byte count for a message."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover


def _parse_size(text: str) -> int:
    text = text.strip().upper().removesuffix("B").removesuffix("I")
    unit = text[-1:] if text[-1:] in _UNITS else ""
    number = float(text[: len(text) - len(unit)])
    if not number > 0:
        raise ValueError(text)
    return int(number * _UNITS[unit])


def total_memory() -> int:
    """Physical memory of this machine in bytes (cgroup limit if lower)."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for cgroup in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(cgroup).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, int(text))
    return total


def memory_limit() -> int:
    """Bytes one command may plan to allocate: ``TACTILE_BENCH_MEMORY_LIMIT`` or 3/4 of RAM.

    Three quarters of the physical memory (not what is free now) keeps the answer the same
    from one run to the next on one machine.
    """
    raw = os.environ.get(MEMORY_LIMIT_ENV)
    if raw:
        try:
            return _parse_size(raw)
        except (ValueError, IndexError):
            raise TactileBenchError(
                f"{MEMORY_LIMIT_ENV}={raw!r}: expected a size such as 8G or 500M"
            ) from None
    return int(total_memory() * MEMORY_SHARE)


def check_memory(key: str, what: str, estimate: float) -> None:
    """Refuse ``key`` when ``what`` would need more than :func:`memory_limit` bytes."""
    limit = memory_limit()
    if estimate > limit:
        source = (
            f"set by {MEMORY_LIMIT_ENV}"
            if os.environ.get(MEMORY_LIMIT_ENV)
            else f"3/4 of this machine's memory; set {MEMORY_LIMIT_ENV} to change it"
        )
        raise TactileBenchError(
            f"{key}: {what} would need about {format_bytes(estimate)} of memory, more than "
            f"the limit of {format_bytes(limit)} ({source})"
        )


def free_space(target: Path) -> tuple[Path, int] | None:
    """The nearest existing folder of ``target`` and the bytes free on its disk (None when
    the disk cannot be asked)."""
    folder = Path(target).absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        return folder, shutil.disk_usage(folder).free
    except OSError:
        return None


#: the errors a write gets from a full disk: no space left, or the user's quota spent
DISK_FULL = frozenset({errno.ENOSPC, errno.EDQUOT})


def disk_full_error(exc: OSError, target: Path) -> TactileBenchError | None:
    """A full disk as one line: the file being written (``exc.filename``, else ``target``)
    and the space left where it goes; None for any other ``OSError``. A write to an open
    file fails without a file name, so the caller says what it was writing."""
    if exc.errno not in DISK_FULL:
        return None
    path = Path(exc.filename) if exc.filename else Path(target)
    doing = "while writing it" if exc.filename else "while writing there"
    space = free_space(path)
    left = f"; {format_bytes(space[1])} free on the disk of {space[0]}" if space else ""
    return TactileBenchError(f"{path}: {os.strerror(exc.errno)} {doing}{left}")


def check_disk(key: str, what: str, estimate: float, target: Path) -> None:
    """Refuse ``key`` when ``what`` would write more than the free space where ``target`` goes."""
    space = free_space(target)
    if space is None:
        return
    folder, free = space
    if estimate > free:
        raise TactileBenchError(
            f"{key}: {what} would write about {format_bytes(estimate)}, more than the "
            f"{format_bytes(free)} free on the disk of {folder}"
        )


def check_int(key: str, value: object, low: int, high: int | None = None) -> int:
    """``value`` as an int in ``[low, high]``, or a one-line error naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise TactileBenchError(f"{key}: must be a whole number, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f"between {low} and {high}" if high is not None else f"at least {low}"
        raise TactileBenchError(f"{key}: must be {bound}, got {value}")
    return value


def check_seed(key: str, value: object) -> int:
    """Seeds are whole numbers in 0 .. 2**32 - 1 (no mapping of negative ones)."""
    return check_int(key, value, 0, SEED_MAX)


def check_unique(key: str, values: object) -> None:
    """A list (or a string of characters) naming the same thing twice is refused."""
    if isinstance(values, (str, list, tuple)):
        seen: set[object] = set()
        for v in values:
            marker = v if isinstance(v, (str, int, float)) else repr(v)
            if marker in seen:
                raise TactileBenchError(f"{key}: {v!r} appears twice")
            seen.add(marker)
