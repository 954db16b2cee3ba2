"""Opt-in timers of named spans of the simulation: where a dataset build spends its time
(and the gap diagnosis: ``diagnose.breakdown``).

The renderers mark their spans with ``with timed_span("sim.optics"):``. Nothing is recorded
(and the cost is one global lookup) unless a ``SpanTimer`` is active, so the builders keep
a single code path for measuring and for real work. Spans nest: a span's time excludes
the spans opened inside it, so the recorded times add up to the timed total.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any, TypeVar

T = TypeVar("T")

_ACTIVE: SpanTimer | None = None


class SpanTimer:
    """Wall and CPU seconds per span (exclusive of nested spans), its wall seconds with
    them (``inclusive``) and how often each span was entered, while active.

    CPU time is the calling thread's, so spans running concurrently in several Python
    threads add up correctly; work a library hands to its own helper threads (torch's
    intra-op pool when it has more than one thread, Embree's scene build) is not counted.
    """

    def __init__(self) -> None:
        self.wall: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self.inclusive: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._local = threading.local()  # per thread: a stack of [child wall, child cpu]
        self._lock = threading.Lock()
        self._previous: SpanTimer | None = None
        self.other_cpu = 0.0  # CPU seconds of other processes that reported here

    def __enter__(self) -> SpanTimer:
        global _ACTIVE
        self._previous, _ACTIVE = _ACTIVE, self
        return self

    def __exit__(self, *exc: object) -> None:
        global _ACTIVE
        _ACTIVE = self._previous

    @contextmanager
    def _span(self, name: str) -> Iterator[None]:
        stack = self._local.__dict__.setdefault("stack", [])
        stack.append([0.0, 0.0])
        w0, c0 = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
            child_wall, child_cpu = stack.pop()
            with self._lock:
                self.wall[name] += wall - child_wall
                self.cpu[name] += cpu - child_cpu
                self.inclusive[name] += wall
                self.calls[name] += 1
            if stack:
                stack[-1][0] += wall
                stack[-1][1] += cpu

    def merge(
        self,
        wall: dict[str, float],
        cpu: dict[str, float],
        process_cpu: float = 0.0,
        calls: dict[str, int] | None = None,
        inclusive: dict[str, float] | None = None,
    ) -> None:
        """Add span times recorded elsewhere (e.g. by a worker process, whose whole CPU
        time ``process_cpu`` goes to ``other_cpu``: the parent's clock does not see it),
        with their call counts and inclusive seconds when given."""
        with self._lock:
            self.other_cpu += process_cpu
            for name, seconds in wall.items():
                self.wall[name] += seconds
            for name, seconds in cpu.items():
                self.cpu[name] += seconds
            for name, count in (calls or {}).items():
                self.calls[name] += count
            for name, seconds in (inclusive or {}).items():
                self.inclusive[name] += seconds

    def merge_times(self, times: dict[str, Any]) -> None:
        """Add the span times ``run_timed`` recorded in another process."""
        self.merge(
            times["wall"], times["cpu"], times["process_cpu"], times["calls"], times["inclusive"]
        )


def run_timed(fn: Callable[..., T], *args: Any) -> tuple[T, dict[str, Any]]:
    """``fn(*args)`` under a fresh ``SpanTimer``: its value and its span times, which a
    worker process sends back for its parent's ``SpanTimer.merge_times``."""
    cpu = time.process_time()
    with SpanTimer() as timer:
        value = fn(*args)
    return value, {
        "wall": dict(timer.wall),
        "cpu": dict(timer.cpu),
        "calls": dict(timer.calls),
        "inclusive": dict(timer.inclusive),
        "process_cpu": time.process_time() - cpu,
    }


def active_timer() -> SpanTimer | None:
    """The ``SpanTimer`` now recording, if any (worker processes report back to it)."""
    return _ACTIVE


@contextmanager
def _nothing() -> Iterator[None]:
    yield


def timed_span(name: str) -> AbstractContextManager[None]:
    """Context manager timing span ``name`` on the active ``SpanTimer``; a no-op without one."""
    timer = _ACTIVE
    return timer._span(name) if timer is not None else _nothing()
