"""Stages that do not read each other, as tasks on a Ray cluster (``executor: ray``).

The side-by-side pool (``jobs: N``) stops at one machine; a table's many small trainings
over seeds and rows do not. With ``executor: ray`` the runner sends every stage whose inputs
are finished to a Ray cluster as a task asking for the CPUs and GPUs it needs, and keeps
everything else as on one machine: it decides what is cached (the same cache keys), the
task reads its inputs from and writes its outputs into the run dir, which must be on
storage every node shares, and the runner writes the manifests. Ray re-runs a task whose
worker or node is lost (``max_retries``); the re-run finds the lost attempt's checkpoint in
the stage's folder and resumes from it.

The cluster is the one ``RAY_ADDRESS`` (or ``ray: {address: ...}``) names, else a local
Ray instance on this machine. Ray is an optional dependency: ``pip install -e '.[cluster]'``.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable
from typing import Any

from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.recipe import RaySettings, Stage
from tactile_bench.pipeline.side_by_side import Ran, execute
from tactile_bench.pipeline.stages.base import StageContext
from tactile_bench.pools import keeping_pools

log = logging.getLogger("tactile_bench")

#: how often Ray re-runs a stage whose worker process or node died
MAX_RETRIES = 3


def _ray() -> Any:
    try:
        import ray
    except ModuleNotFoundError:
        raise TactileBenchError(
            "executor: ray needs the ray package: pip install -e '.[cluster]'"
        ) from None
    return ray


def stage_needs(stage: Stage, trainer: dict[str, Any], settings: RaySettings) -> dict[str, float]:
    """The Ray resources a stage's task asks for: ``cpus_per_stage`` CPUs, and one GPU for a
    stage that runs networks (it trains, or its precision depends on the device) when the
    trainer's accelerator is a GPU."""
    gpu = str(trainer.get("accelerator", "cpu")).lower() in ("gpu", "cuda")
    networks = stage.kind.fits or stage.kind.precision_dependent
    return {"num_cpus": settings.cpus_per_stage, "num_gpus": 1 if gpu and networks else 0}


def execute_stage(stage: Stage, ctx: StageContext, threads: int, level: int) -> Ran:
    """A stage, run in a Ray worker on ``threads`` threads (its task's CPUs), without
    progress bars (several tasks share a terminal)."""
    import torch

    from tactile_bench.allocator import keep_freed_memory
    from tactile_bench.console import configure_logging

    keep_freed_memory()
    configure_logging(level)
    torch.set_num_threads(threads)
    ctx = dataclasses.replace(
        ctx, progress=False, trainer={**ctx.trainer, "enable_progress_bar": False}
    )
    with keeping_pools():  # a Ray worker outlives the task: its seed pool does not
        return execute(stage, ctx)


def run_on_ray(
    stages: list[Stage],
    start: Callable[[Stage, dict[str, Any]], tuple[Any, StageContext | None]],
    finish: Callable[[Stage, Any, Ran], Any],
    trainer: dict[str, Any],
    settings: RaySettings,
) -> dict[str, Any]:
    """Every stage's result, each ready stage a Ray task (``start``/``finish`` as for
    ``side_by_side.run_side_by_side``, called here, in the order stages become ready)."""
    from tactile_bench.pipeline.side_by_side import ready

    ray = _ray()
    address = settings.address or os.environ.get("RAY_ADDRESS")
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, include_dashboard=False, log_to_driver=True)
    level = logging.getLogger("tactile_bench").getEffectiveLevel()
    remote = ray.remote(max_retries=MAX_RETRIES)(execute_stage)
    results: dict[str, Any] = {}
    waiting = list(stages)
    running: dict[Any, tuple[Stage, Any]] = {}
    try:
        while waiting or running:
            for stage in list(waiting):
                if not ready(stage, stages, results):
                    continue
                waiting.remove(stage)
                handle, ctx = start(stage, results)
                if ctx is None:
                    results[stage.name] = handle
                    continue
                needs = stage_needs(stage, trainer, settings)
                log.info("stage %s: sent to Ray (%s)", stage.name, _describe(needs))
                threads = max(1, int(needs["num_cpus"]))
                ref = remote.options(**needs).remote(stage, ctx, threads, level)
                running[ref] = (stage, handle)
            if not running:
                if waiting:
                    raise TactileBenchError(f"stage {waiting[0].name}: its inputs never ran")
                break
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                stage, handle = running.pop(ref)
                results[stage.name] = finish(stage, handle, _result(ray, stage, ref))
    except BaseException:
        for ref in running:  # a failure or an interrupt: the other stages stop too
            ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()
    return {stage.name: results[stage.name] for stage in stages}


def _describe(needs: dict[str, float]) -> str:
    return f"{needs['num_cpus']:g} CPU" + (
        f", {needs['num_gpus']:g} GPU" if needs["num_gpus"] else ""
    )


def _result(ray: Any, stage: Stage, ref: Any) -> Ran:
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = exc.cause if isinstance(exc.cause, BaseException) else None
        if isinstance(cause, TactileBenchError):
            raise type(cause)(str(cause)) from None
        raise
    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as exc:
        raise TactileBenchError(
            f"stage {stage.name}: its Ray worker was lost {MAX_RETRIES + 1} times "
            f"({type(exc).__name__}); finished stages and its checkpoint are kept"
        ) from None
