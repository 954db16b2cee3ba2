"""The diagnosis's fits side by side in worker processes.

Each fit of a round (a candidate alone or with the selected ones, a swapped rival's
coalition) reads the same splits and draws from its own seeded generators, never from what
another fit writes, so the fits of a round give the same results in any process and any
order (up to the float rounding of torch's threads: one a worker). A machine with more cores
than torch's intra-op threads can use on a few dozen 64 px images then fits several
candidates at once; on 2 cores one process of two threads is as fast
(docs/results/diagnosis_speed.md), so this is opt-in.

``fit_workers(n)`` opens ``n`` spawned workers for a block (``diagnose --workers N``);
``map_fits`` runs a list of fits in them, or one after the other in this process when none
are open. The optical-response lookups a worker fits are sent back and cached here; a
worker's timed spans are added to this process's ``SpanTimer`` (summed over the workers:
process seconds, not wall).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any, TypeVar

from tactile_bench.diagnose.breakdown import WAIT_WORKERS
from tactile_bench.errors import TactileBenchError
from tactile_bench.pools import cancel_pending, one_thread_worker, spawned_pool
from tactile_bench.sensor.timing import SpanTimer, active_timer, run_timed, timed_span

T = TypeVar("T")
#: most workers ``auto`` opens: a round fits at most 14 candidates, and each worker holds
#: its own torch (about 300 MB)
MAX_AUTO_WORKERS = 8
MAX_WORKERS = 64  # more processes than any round has fits

_POOL: ProcessPoolExecutor | None = None  # the open workers


def auto_workers() -> int:
    """Workers for this machine: one per usable core, at most ``MAX_AUTO_WORKERS``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(cores or 1, MAX_AUTO_WORKERS))


def parse_workers(value: str | int | None, key: str = "--workers") -> int:
    """``auto`` (or None) -> ``auto_workers()``; else a positive whole number."""
    if value is None or value == "auto":
        return auto_workers()
    try:
        n = int(value)
    except ValueError:
        n = 0
    if not 1 <= n <= MAX_WORKERS:
        raise TactileBenchError(
            f"{key}: 'auto' or a whole number from 1 to {MAX_WORKERS}, got {value!r}"
        )
    return n


@contextmanager
def fit_workers(n: int) -> Iterator[None]:
    """Within the block, ``map_fits`` spreads fits over ``n`` spawned processes (1: none,
    the fits run here). Opened once per command: a worker's start-up (importing torch) costs
    seconds."""
    global _POOL
    if n <= 1 or _POOL is not None:
        yield
        return
    with spawned_pool(n, initializer=one_thread_worker) as pool:
        _POOL = pool
        try:
            yield
        finally:
            _POOL = None


def _in_worker(
    fn: Callable[..., T], args: tuple[Any, ...], reference: Any, timing: bool
) -> tuple[T, dict[str, Any], dict[str, Any] | None]:
    """``fn(*args)`` in a worker: its value, the lookups it added to ``reference`` and,
    when the parent times, its spans."""
    known = set(reference.lookups) if reference is not None else set()
    value, times = run_timed(fn, *args) if timing else (fn(*args), None)
    added = {} if reference is None else {
        k: v for k, v in reference.lookups.items() if k not in known
    }  # fmt: skip
    return value, added, times


def map_fits(
    fn: Callable[..., T],
    calls: Sequence[tuple[Any, ...]],
    reference: Any = None,
    done: Callable[[int], None] | None = None,
) -> list[T]:
    """``[fn(*args) for args in calls]``, in the open workers when there are any.

    ``fn`` must be a module-level function (workers import it by name); ``reference``: the
    ``scene.FitReference`` the calls share, whose new lookups come back into its cache;
    ``done(i)``: called as call ``i`` finishes (a progress bar).
    """
    if _POOL is None or len(calls) < 2:
        out = []
        for i, args in enumerate(calls):
            out.append(fn(*args))
            if done is not None:
                done(i)
        return out
    pool = _POOL
    timer = active_timer()
    with timed_span(WAIT_WORKERS):
        futures: dict[Future[Any], int] = {
            pool.submit(_in_worker, fn, args, reference, timer is not None): i
            for i, args in enumerate(calls)
        }
        results: list[Any] = [None] * len(calls)
        try:
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when="FIRST_COMPLETED")
                for future in finished:
                    i = futures[future]
                    results[i] = _collect(future, reference, timer)
                    if done is not None:
                        done(i)
        except BrokenProcessPool as err:
            raise TactileBenchError(
                f"diagnosis: a fit's worker process died ({err}); rerun with --workers 1"
            ) from err
        finally:  # an error or an interrupt: do not leave the workers busy with the rest
            cancel_pending(futures)
    return results


def _collect(future: Future[Any], reference: Any, timer: SpanTimer | None) -> Any:
    """A finished call's value; its lookups cached here, its spans added to ``timer``."""
    value, added, times = future.result()
    if reference is not None:
        for key, table in added.items():
            reference.lookups.setdefault(key, table)
    if timer is not None and times is not None:
        timer.merge_times(times)
    return value
