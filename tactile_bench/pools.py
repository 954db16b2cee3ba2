"""Process pools of spawned workers that end with the work they serve.

Every place that starts worker processes (the corpus builder, a classify stage's seeds, the
side-by-side runner) takes its pool from here. :func:`spawned_pool` is a ``with`` block:
when the block ends, normally, by an error or by Ctrl-C, the pending work is cancelled and
the workers are stopped and joined. :func:`kept_pool` is one pool a process reuses from
stage to stage (each worker's start-up imports torch and Lightning: seconds a stage), and
ends with the run: :func:`close_kept_pools` (the runner's ``keeping_pools`` block), or in a
process that is itself a pool worker, before that process's exit joins its children.

That order is what lets a worker process exit: at exit, multiprocessing joins a worker's
live children before anything else (``atexit`` handlers do not run in a multiprocessing
child at all), and an idle pool worker waits for work for ever, so a pool still open there
would hang the run after its last stage. A kept pool is shut down by a multiprocessing
finaliser that runs before that join.

Workers are spawned, not forked: a forked child cannot use the parent's OpenMP or Embree
thread pools. Tensors reach them through shared-memory files (torch's ``file_system``
sharing strategy: file descriptors run out in containers).
"""

from __future__ import annotations

import multiprocessing.util
import os
import signal
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager, suppress
from typing import Any

import torch
import torch.multiprocessing


@contextmanager
def spawned_pool(
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: tuple[Any, ...] = (),
) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` spawned processes for the length of the ``with`` block.

    On leaving the block every future not yet running is cancelled and the workers are
    joined; a future still running is waited for (callers cancel or signal their own work
    first, see :func:`signal_workers`).
    """
    if workers < 1:
        raise ValueError(f"a pool needs at least one worker, got {workers}")
    torch.multiprocessing.set_sharing_strategy("file_system")
    pool = ProcessPoolExecutor(
        workers,
        mp_context=torch.multiprocessing.get_context("spawn"),
        initializer=initializer,
        initargs=initargs,
    )
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def one_thread_worker() -> None:
    """A pool's initializer: torch on one thread (one process per core, no intra-op threads
    on top) and malloc keeping freed tensor memory (``tactile_bench.allocator``: the pool
    owns its processes)."""
    from tactile_bench.allocator import keep_freed_memory

    torch.set_num_threads(1)
    keep_freed_memory()


#: this process's kept pools, by worker count
_KEPT: dict[int, ProcessPoolExecutor] = {}


def kept_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes that this process's later stages reuse.

    Shut down by :func:`close_kept_pools`, and in any case before this process's exit joins
    its children (a finaliser above the priority of the pool's own queues, which must still
    carry the stop messages). A pool that broke is dropped with :func:`forget_kept_pool`.
    """
    if workers < 1:
        raise ValueError(f"a pool needs at least one worker, got {workers}")
    pool = _KEPT.get(workers)
    if pool is None:
        torch.multiprocessing.set_sharing_strategy("file_system")
        pool = ProcessPoolExecutor(workers, mp_context=torch.multiprocessing.get_context("spawn"))
        multiprocessing.util.Finalize(pool, _shut_down, args=(pool,), exitpriority=100)
        _KEPT[workers] = pool
    return pool


def _shut_down(pool: ProcessPoolExecutor) -> None:
    pool.shutdown(wait=True, cancel_futures=True)


def forget_kept_pool(workers: int) -> None:
    """Drop (and shut down without waiting) the kept pool of ``workers``: it broke."""
    pool = _KEPT.pop(workers, None)
    if pool is not None:
        pool.shutdown(wait=False, cancel_futures=True)


def close_kept_pools() -> None:
    """Stop and join every kept pool of this process."""
    while _KEPT:
        _, pool = _KEPT.popitem()
        _shut_down(pool)


@contextmanager
def keeping_pools() -> Iterator[None]:
    """Kept pools made inside the block are closed when it ends (a run's stages)."""
    try:
        yield
    finally:
        close_kept_pools()


def cancel_pending(futures: Iterable[Future[Any]]) -> None:
    """Cancel every future of ``futures`` that has not started."""
    for future in futures:
        future.cancel()


def signal_workers(pool: ProcessPoolExecutor, signum: int = signal.SIGTERM) -> None:
    """Send ``signum`` to every live worker of ``pool`` (each saves its checkpoint on
    SIGTERM, as the command line does on Ctrl-C)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive() and process.pid is not None:
            with suppress(ProcessLookupError):
                os.kill(process.pid, signum)
