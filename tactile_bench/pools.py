"""Process pools of spawned workers that end with the work they serve.

Every place that starts worker processes (the corpus builder, a classify stage's seeds, the
side-by-side runner) takes its pool from :func:`spawned_pool`, a ``with`` block: when the
block ends, normally, by an error or by Ctrl-C, the pending work is cancelled and the
workers are stopped and joined. No pool outlives the stage that made it.

That is what lets a process that is itself a worker exit: at exit, multiprocessing joins a
worker's live children before anything else (``atexit`` handlers do not run in a
multiprocessing child at all), and an idle pool worker waits for work for ever, so a pool
left open by a side-by-side stage hung the run after its last stage.

Workers are spawned, not forked: a forked child cannot use the parent's OpenMP or Embree
thread pools. Tensors reach them through shared-memory files (torch's ``file_system``
sharing strategy: file descriptors run out in containers).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager, suppress
from typing import Any

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
