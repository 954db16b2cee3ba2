"""Timing and memory primitives of the benchmark: warm-up, repetitions, medians, peak RSS.

Wall time (``time.perf_counter``) is what a user waits; CPU time of this process
(``time.process_time``) is reported beside it because on a shared, busy machine it moves
less. Peak memory is the resident set size (RSS) of the process, sampled every couple of
milliseconds from ``/proc/self/statm`` by a background thread while the measured work runs:
``tracemalloc`` would miss torch's tensors (allocated in C++), and ``ru_maxrss`` is a
high-water mark of the whole process that never comes down, so its deltas miss any peak
lower than an earlier one. Where ``/proc`` is absent the sampler falls back to
``ru_maxrss`` deltas and says so (``peak_source``).
"""

from __future__ import annotations

import ctypes
import gc
import os
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any

import torch

from tactile_bench.pipeline.memory import peak_rss_mib

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_STATM = "/proc/self/statm"


def rss_bytes() -> int | None:
    """Current resident set size of this process, or None where /proc is absent."""
    try:
        with open(_STATM) as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def _maxrss_bytes() -> int:
    return round(peak_rss_mib() * 2**20)


@dataclass
class PeakMemory:
    """Peak RSS above the RSS at the start of the block, in MiB (filled in on exit)."""

    interval_s: float = 0.002
    start_mib: float = 0.0
    peak_mib: float = 0.0
    source: str = "rss-sampler"

    @property
    def delta_mib(self) -> float:
        return max(0.0, self.peak_mib - self.start_mib)


def _trim_heap() -> None:
    """Give freed heap pages back to the OS (glibc ``malloc_trim``), so the starting RSS
    does not already hold memory the measured block would otherwise have to allocate."""
    with suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


@contextmanager
def polling(poll: Callable[[], None], interval_s: float) -> Iterator[None]:
    """Call ``poll`` every ``interval_s`` in a background thread while the block runs."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            poll()
            stop.wait(interval_s)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


@contextmanager
def peak_memory(interval_s: float = 0.002) -> Iterator[PeakMemory]:
    """Sample RSS in a thread while the block runs; ``delta_mib`` is what the block added.

    The heap is trimmed first; memory the allocator still keeps (fragments, other arenas) is
    counted in the start RSS, so a block that reuses it shows a smaller delta than in a
    fresh process: the figure is a lower bound of the block's working memory.
    """
    gc.collect()
    _trim_heap()
    out = PeakMemory(interval_s=interval_s)
    start = rss_bytes()
    if start is None:  # no /proc: high-water-mark deltas (see module docstring)
        out.source = "ru_maxrss-delta"
        before = _maxrss_bytes()
        out.start_mib = before / 2**20
        try:
            yield out
        finally:
            out.peak_mib = max(before, _maxrss_bytes()) / 2**20
        return
    peak = [start]

    def poll() -> None:
        peak[0] = max(peak[0], rss_bytes() or 0)

    try:
        with polling(poll, interval_s):
            yield out
    finally:
        peak[0] = max(peak[0], rss_bytes() or 0)
        out.start_mib = start / 2**20
        out.peak_mib = peak[0] / 2**20


@dataclass
class Timing:
    """Repeated measurements of one piece of work; ``work`` is its size (images, contacts)."""

    wall_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    work: float = 1.0
    peak_mib: float = 0.0

    @property
    def median_wall_s(self) -> float:
        return statistics.median(self.wall_s)

    @property
    def median_cpu_s(self) -> float:
        return statistics.median(self.cpu_s)

    @property
    def per_s(self) -> float:
        """Work per wall-clock second, from the median repetition."""
        return self.work / self.median_wall_s

    @property
    def per_cpu_s(self) -> float:
        """Work per CPU second of this process (all threads), from the median repetition."""
        return self.work / max(self.median_cpu_s, 1e-9)

    @property
    def spread(self) -> float:
        """(max - min) / median of the wall times: how noisy the repetitions were."""
        if len(self.wall_s) < 2:
            return 0.0
        return (max(self.wall_s) - min(self.wall_s)) / self.median_wall_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "work": self.work,
            "wall_s": [round(t, 6) for t in self.wall_s],
            "cpu_s": [round(t, 6) for t in self.cpu_s],
            "median_wall_s": round(self.median_wall_s, 6),
            "per_s": self.per_s,
            "per_cpu_s": self.per_cpu_s,
            "spread": round(self.spread, 4),
            "peak_mib": round(self.peak_mib, 1),
        }


def measure(
    run: Callable[[], object],
    work: float,
    repeats: int = 3,
    warmup: int = 1,
    memory: bool = True,
) -> Timing:
    """Run ``warmup`` untimed calls, then ``repeats`` timed ones; keep every time.

    The warm-up pays one-off costs (oneDNN kernel selection, allocator growth, lazy
    imports) that would otherwise land in the first repetition. Peak memory is taken over
    the timed repetitions.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    for _ in range(warmup):
        run()
    timing = Timing(work=float(work))
    with peak_memory() if memory else _nothing() as mem:
        for _ in range(repeats):
            w0, c0 = time.perf_counter(), time.process_time()
            run()
            timing.wall_s.append(time.perf_counter() - w0)
            timing.cpu_s.append(time.process_time() - c0)
    timing.peak_mib = mem.delta_mib if mem is not None else 0.0
    return timing


@contextmanager
def _nothing() -> Iterator[None]:
    yield None


@contextmanager
def torch_threads(threads: int | None) -> Iterator[int]:
    """Set torch's intra-op threads for a block (None keeps them) and restore them after."""
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield torch.get_num_threads()
    finally:
        torch.set_num_threads(before)
