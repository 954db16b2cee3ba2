"""Stages that do not read each other, run side by side in worker processes (``jobs: N``).

A network stage on two threads keeps its second core busy only part of the time (Python,
Lightning's loop, data loading and the small tensors of a fit run on one), and a data or
diagnosis stage mostly on one. Run one after another, a 2-core machine idled about a
quarter of quick.yaml (docs/results/precision.md). With ``jobs: N`` the runner starts every
stage whose inputs are finished, up to N at a time, each in its own spawned process on
``cores // N`` threads; a stage that summarises the run (``waits_for_earlier``: the
report) waits for every stage listed before it.

What a stage computes does not change: it reads the same input files and writes the same
outputs under the same cache key. Only the thread count of each stage differs, which moves
float sums in their last bits, as another machine would. Each worker's log lines go to the
same stderr; progress bars are off in workers (two would interleave).

Stopping: Ctrl-C reaches every process of the terminal's group, so each running stage
saves its checkpoint as it would alone; a SIGTERM to the runner is passed on to the
workers. Either way the runner waits for them to finish saving, then raises
``KeyboardInterrupt`` (exit 130). A stage that fails stops the others the same way (their
checkpoints are kept), and its error is raised.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import signal
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any

import torch

from tactile_bench.allocator import keep_freed_memory
from tactile_bench.console import configure_logging
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.limits import disk_full_error
from tactile_bench.hardware import use_tensor_cores
from tactile_bench.pipeline.memory import peak_rss_mib
from tactile_bench.pipeline.recipe import Stage
from tactile_bench.pipeline.stages.base import StageContext
from tactile_bench.pools import signal_workers, spawned_pool

log = logging.getLogger("tactile_bench")

#: what a stage's run hands back: outputs, metrics, wall time (s), its process's peak RSS
Ran = tuple[dict[str, str], dict[str, Any], float, float]


def execute(stage: Stage, ctx: StageContext) -> Ran:
    """Run one stage here; its errors name it, and an interrupt says what was kept."""
    start = time.perf_counter()
    use_tensor_cores()
    try:
        outputs, metrics = stage.kind.run(ctx)
    except TactileBenchError as exc:
        message = str(exc)
        if not message.startswith(f"stage {stage.name}"):
            message = f"stage {stage.name}: {message}"
        raise type(exc)(message) from None  # its class too: callers tell kinds apart
    except OSError as exc:  # a full disk: the stage, the file and the space left
        full = disk_full_error(exc, ctx.directory)
        if full is None:
            raise
        raise TactileBenchError(f"stage {stage.name}: {full}") from None
    except KeyboardInterrupt:
        log.warning(
            "stage %s interrupted: finished stages and its training checkpoint (if any) are "
            "kept in %s; rerun the same command to resume",
            stage.name,
            ctx.directory,
        )
        raise
    finally:
        # a fitted stage leaves its trainer, model and data in reference cycles that only a
        # full collection frees: without this, each classifier stage of table1.yaml kept
        # ~1.4 GB alive into the next one (docs/results/precision.md, "Memory between stages")
        gc.collect()
    return outputs, metrics, time.perf_counter() - start, peak_rss_mib()


def _start_worker(threads: int, level: int) -> None:
    """A worker's process-wide settings, as the command line sets them for itself."""
    keep_freed_memory()
    torch.set_num_threads(threads)
    configure_logging(level)


def _execute_in_worker(stage: Stage, ctx: StageContext) -> Ran:
    ctx = dataclasses.replace(
        ctx, progress=False, trainer={**ctx.trainer, "enable_progress_bar": False}
    )
    return execute(stage, ctx)


def _threads_per_job(jobs: int) -> int:
    """Each of ``jobs`` side-by-side stages gets an equal share of this process's threads."""
    return max(1, torch.get_num_threads() // jobs)


@contextmanager
def _sigterm_to_workers(pool: ProcessPoolExecutor) -> Iterator[None]:
    """While the pool runs: a SIGTERM to the runner reaches its workers (each saves its
    checkpoint), and the runner itself stops as on Ctrl-C."""

    def handler(signum: int, frame: Any) -> None:
        signal_workers(pool, signal.SIGTERM)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_side_by_side(
    stages: list[Stage],
    jobs: int,
    start: Callable[[Stage, dict[str, Any]], tuple[Any, StageContext | None]],
    finish: Callable[[Stage, Any, Ran], Any],
) -> dict[str, Any]:
    """Every stage's result, ``jobs`` stages at a time as their inputs finish.

    ``start(stage, results)`` returns ``(result, None)`` for a stage taken from the cache
    and ``(handle, ctx)`` for one to run; ``finish(stage, handle, ran)`` turns a run into
    its result. Both run in this process, in the order stages become ready.
    """
    results: dict[str, Any] = {}
    waiting = list(stages)
    running: dict[Future[Ran], tuple[Stage, Any]] = {}
    level = logging.getLogger("tactile_bench").getEffectiveLevel()
    initargs = (_threads_per_job(jobs), level)
    with spawned_pool(jobs, _start_worker, initargs) as pool, _sigterm_to_workers(pool):
        try:
            while waiting or running:
                _submit_ready(stages, waiting, running, results, jobs, pool, start)
                if not running:
                    if waiting:  # the recipe loader refuses references to later stages
                        raise TactileBenchError(f"stage {waiting[0].name}: its inputs never ran")
                    break
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    stage, handle = running.pop(future)
                    results[stage.name] = finish(stage, handle, _ran(stage, future))
        except BaseException:
            # a failure or an interrupt: the other running stages save and stop, then this
            # raises
            signal_workers(pool, signal.SIGTERM)
            wait(running)
            raise
    return {stage.name: results[stage.name] for stage in stages}


def _ran(stage: Stage, future: Future[Ran]) -> Ran:
    try:
        return future.result()
    except BrokenProcessPool:
        raise TactileBenchError(
            f"stage {stage.name}: its worker process died (out of memory?); "
            "--jobs 1 runs the stages one at a time in this process"
        ) from None


def _submit_ready(
    stages: list[Stage],
    waiting: list[Stage],
    running: dict[Future[Ran], tuple[Stage, Any]],
    results: dict[str, Any],
    jobs: int,
    pool: ProcessPoolExecutor,
    start: Callable[[Stage, dict[str, Any]], tuple[Any, StageContext | None]],
) -> None:
    """Start waiting stages whose inputs are finished, in recipe order, while a job is free.
    One pass suffices: a stage reads only earlier ones, so a stage found in the cache (it
    finishes at once) can make only stages later in the pass ready."""
    for stage in list(waiting):
        if len(running) >= jobs:
            return
        if not ready(stage, stages, results):
            continue
        waiting.remove(stage)
        handle, ctx = start(stage, results)
        if ctx is None:
            results[stage.name] = handle
        else:
            running[pool.submit(_execute_in_worker, stage, ctx)] = (stage, handle)


def ready(stage: Stage, stages: list[Stage], results: dict[str, Any]) -> bool:
    """Whether every stage ``stage`` reads (all earlier ones for a report) has finished."""
    if stage.kind.waits_for_earlier:
        earlier = stages[: stages.index(stage)]
        return all(s.name in results for s in earlier)
    return all(ref in results for refs in stage.inputs.values() for ref in refs)
