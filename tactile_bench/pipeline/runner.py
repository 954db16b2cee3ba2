"""Run a recipe's stages in order, each cached under a directory keyed by its config and inputs.

A stage's key hashes its kind, config, the run settings and the *content*
hashes of the stages it reads, so an upstream change reruns everything
downstream and nothing else. A stage is finished when its ``_done.json``
manifest exists and every file it lists still has the recorded hash: a
corrupted or truncated entry is rebuilt, never used. Work in progress lives in
the same directory (Lightning checkpoints), so a killed run resumes there.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path
from typing import Any

import tactile_bench
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.outputs import OutputLock, check_output_dir
from tactile_bench.hardware import (
    compute_device,
    describe_device,
    resolve_precision,
    trainer_device,
)
from tactile_bench.io import atomic_write_json, file_sha256, json_sha256
from tactile_bench.pipeline.launch import LAUNCH_KEYS, Launch, gather, share
from tactile_bench.pipeline.launch import finish as finish_launch
from tactile_bench.pipeline.launch import start as start_launch
from tactile_bench.pipeline.provenance import InputHasher, run_record
from tactile_bench.pipeline.ranks import (
    LostProcess,
    follow,
    lead,
    sigterm_ends_launch,
    stop_followers,
)
from tactile_bench.pipeline.recipe import Recipe, Stage
from tactile_bench.pipeline.run_lock import RunDirLock, check_claim
from tactile_bench.pipeline.side_by_side import Ran, execute, run_side_by_side
from tactile_bench.pipeline.stages.base import StageContext, StageResult
from tactile_bench.pools import keeping_pools
from tactile_bench.training import processes, result_settings

log = logging.getLogger("tactile_bench")
DONE = "_done.json"


def stage_key(
    recipe: Recipe,
    stage: Stage,
    inputs: dict[str, list[StageResult]],
    files: dict[str, str] | None = None,
) -> str:
    """Short hash of everything that determines a stage's outputs: its config, the content of
    the stages and user files it reads (``files``: path -> sha256), seed, trainer, version.
    Trainer settings that only change display or checkpoint frequency are left out, so
    changing them does not lose a killed stage's checkpoint. A stage whose networks' precision
    can come from ``auto`` also hashes what ``auto`` resolves to on this machine.

    How many processes train (``strategy``, ``devices``, ``num_nodes``) is hashed only for a
    stage that trains (``StageKind.fits``), and only when more than one: their batches add up
    to one optimizer step (the effective batch); a data or report stage is the same however
    many processes the run has."""
    settings = result_settings(recipe.trainer)
    doc: dict[str, Any] = {
        "kind": stage.kind.name,
        "config": stage.config.model_dump(mode="json"),
        "inputs": {slot: [r.manifest_hash for r in rs] for slot, rs in sorted(inputs.items())},
        "seed": recipe.seed,
        "trainer": {k: v for k, v in settings.items() if k not in LAUNCH_KEYS},
        "version": tactile_bench.__version__,
    }
    if stage.kind.fits and processes(settings) > 1:
        doc["processes"] = processes(settings)
        doc["strategy"] = settings["strategy"]
    if stage.kind.precision_dependent:
        device = trainer_device(recipe.trainer.get("accelerator"))
        doc["auto_precision"] = resolve_precision("auto", device)
    if files:
        doc["files"] = files
    return json_sha256(doc)[:12]


def read_done(directory: Path) -> StageResult | None:
    """A finished stage's result, or None when absent or any listed file fails its hash."""
    manifest_path = directory / DONE
    if not manifest_path.exists():
        return None
    try:
        manifest = json.loads(manifest_path.read_text())
        for name, entry in manifest["outputs"].items():
            file = directory / entry["file"]
            if not file.exists() or file_sha256(file) != entry["sha256"]:
                log.warning(
                    "cache entry %s: %s is missing or corrupted; rebuilding", directory, name
                )
                return None
        return StageResult(
            name=manifest["name"],
            kind=manifest["kind"],
            directory=directory,
            outputs={k: v["file"] for k, v in manifest["outputs"].items()},
            metrics=manifest["metrics"],
            manifest_hash=json_sha256(manifest["outputs"]),
            wall_time_s=manifest["wall_time_s"],
            peak_rss_mib=manifest.get("peak_rss_mib"),
            cached=True,
        )
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("cache entry %s: unreadable manifest; rebuilding", directory)
        return None


def _finish(
    stage: Stage,
    directory: Path,
    outputs: dict[str, str],
    metrics: dict[str, Any],
    wall: float,
    peak_mib: float | None = None,
) -> StageResult:
    listed = {}
    for name, rel in outputs.items():
        file = directory / rel
        if not file.exists():
            raise TactileBenchError(
                f"stage {stage.name!r} did not write its output {name!r} ({rel})"
            )
        listed[name] = {"file": rel, "sha256": file_sha256(file)}
    manifest = {
        "name": stage.name,
        "kind": stage.kind.name,
        "config": stage.config.model_dump(mode="json"),
        "outputs": listed,
        "metrics": metrics,
        "wall_time_s": round(wall, 3),
        "peak_rss_mib": None if peak_mib is None else round(peak_mib, 1),
        "version": tactile_bench.__version__,
    }
    atomic_write_json(directory / DONE, manifest)
    return StageResult(
        stage.name,
        stage.kind.name,
        directory,
        outputs,
        metrics,
        json_sha256(listed),
        wall,
        peak_rss_mib=peak_mib,
    )


def _publish(result: StageResult, names: tuple[str, ...], run_dir: Path) -> None:
    for name in names:
        if name in result.outputs:
            src = result.path(name)
            tmp = run_dir / f".{src.name}.tmp"
            shutil.copyfile(src, tmp)
            tmp.replace(run_dir / src.name)


def run_recipe(
    recipe: Recipe, force: tuple[str, ...] = (), progress: bool = True
) -> list[StageResult]:
    """Run (or reuse) every stage; returns their results in order. With ``recipe.jobs`` > 1,
    stages that do not read each other run side by side (``side_by_side``); with
    ``executor: ray``, as tasks on a Ray cluster (``ray_executor``). Started by torchrun,
    srun or with ``strategy: ddp`` on several devices, this is one rank of a launch
    (``launch``): rank 0 runs the recipe and returns its results, the others train with it
    and return nothing.

    Writes ``run.json``: seeds, versions, platform, the hash of the recipe and of every user
    file the recipe names, and each stage's config and output hashes (see ``provenance``).
    """
    for name in force:
        recipe.stage(name)  # unknown names fail before any work
    launch, recipe.trainer = start_launch(recipe.trainer)
    if launch is not None:
        return _run_launched(recipe, launch, force, progress)
    check_output_dir(recipe.run_dir, "run dir")
    # a second run on this run dir would do the same work and overwrite the first's files
    with OutputLock(recipe.run_dir, "run dir"), keeping_pools():
        return _run_locked(recipe, force, progress)


def _run_launched(
    recipe: Recipe, launch: Launch, force: tuple[str, ...], progress: bool
) -> list[StageResult]:
    """One rank of a launch (``pipeline.launch``): rank 0 runs the recipe as
    :func:`_run_locked` does, holding a lock other machines see; the others follow it
    (``pipeline.ranks``). Returns the results on rank 0, nothing on the others."""
    if recipe.executor != "local":
        raise TactileBenchError(
            f"executor: {recipe.executor} under a launch of {launch.world_size} processes: "
            "a launch trains each fit on all of its processes; run one or the other"
        )
    if recipe.jobs > 1:
        log.info(
            "jobs: %d -> 1 under a launch of %d processes (each fit already uses all of them)",
            recipe.jobs,
            launch.world_size,
        )
        recipe.jobs = 1
    if not launch.leader:
        lock = share(launch)
        if lock[0] == "stop":
            raise TactileBenchError(
                f"{launch.describe()}: stopped with rank 0 (its error says why)"
            )
        problem = check_claim(recipe.run_dir, launch.launch_id)
        seen = gather(launch, problem)
        if problem is not None:
            raise TactileBenchError(f"{launch.describe()}: run dir {recipe.run_dir}: {problem}")
        del seen  # a rank that does not see the run dir: rank 0 stops everyone
        follow(launch)
        finish_launch(launch)
        return []
    try:
        check_output_dir(recipe.run_dir, "run dir")
        with sigterm_ends_launch(), RunDirLock(recipe.run_dir, launch.launch_id):
            share(launch, ("locked",))
            unseen = [f"rank {r}: {p}" for r, p in enumerate(gather(launch, None)) if p]
            if unseen:
                raise TactileBenchError(
                    f"run dir {recipe.run_dir}: not on storage every rank shares ({unseen[0]}); "
                    "put it where all nodes see the same files"
                )
            results = _run_locked(recipe, force, progress, launch)
    except LostProcess:
        raise  # no one to tell, and a follower may be inside a collective
    except BaseException as exc:
        stop_followers(launch, str(exc) or type(exc).__name__)
        raise
    finish_launch(launch)
    return results


def _run_locked(
    recipe: Recipe, force: tuple[str, ...], progress: bool, launch: Launch | None = None
) -> list[StageResult]:
    recipe.run_dir.mkdir(parents=True, exist_ok=True)
    hasher = InputHasher(recipe.run_dir, recipe.path.parent)

    def start(stage: Stage, results: dict[str, StageResult]) -> tuple[Any, StageContext | None]:
        """The cached result, or the stage's directory made ready and the context to run it."""
        inputs = {slot: [results[r] for r in refs] for slot, refs in stage.inputs.items()}
        files = hasher.config_files(stage.config.model_dump(mode="json"))
        directory = recipe.run_dir / f"{stage.name}-{stage_key(recipe, stage, inputs, files)}"
        if stage.name in force and directory.exists():
            shutil.rmtree(directory)
        cached = read_done(directory)
        if cached is not None:
            log.info("stage %s: finished before, reusing %s", stage.name, directory)
            _publish(cached, stage.kind.publish, recipe.run_dir)
            return cached, None
        (directory / DONE).unlink(missing_ok=True)
        directory.mkdir(parents=True, exist_ok=True)
        log.info("stage %s (%s): running in %s", stage.name, stage.kind.name, directory)
        if stage.kind.precision_dependent:
            device = compute_device(recipe.trainer.get("accelerator"))
            log.info(
                "stage %s: networks on %s, precision auto = %s",
                stage.name,
                describe_device(device),
                resolve_precision("auto", device.type),
            )
        trainer = dict(recipe.trainer)
        if not progress:  # --no-progress silences Lightning's bars too (not in any key)
            trainer.setdefault("enable_progress_bar", False)
        before = recipe.stages[: recipe.stages.index(stage)]
        earlier = [results[s.name] for s in before if s.name in results]
        ctx = StageContext(
            stage.name,
            directory,
            _one_seed_at_a_time(stage) if launch is not None else stage.config,
            inputs,
            recipe.seed,
            trainer,
            recipe.run_dir,
            recipe.path.parent,
            progress,
            previous=earlier,
        )
        return directory, ctx

    def finish(stage: Stage, directory: Path, ran: Ran) -> StageResult:
        outputs, metrics, wall, peak = ran
        trained_on = processes(recipe.trainer)
        if stage.kind.fits and trained_on > 1:  # the report says the effective batch grew
            metrics = {**metrics, "processes": trained_on}
        result = _finish(stage, directory, outputs, metrics, wall, peak)
        log.info(
            "stage %s: done in %.1f s (peak RSS of its process so far %.0f MiB)",
            stage.name,
            result.wall_time_s,
            result.peak_rss_mib,
        )
        _publish(result, stage.kind.publish, recipe.run_dir)
        return result

    if launch is not None:
        results = lead(launch, recipe.stages, start, finish)
    elif recipe.executor == "ray":
        from tactile_bench.pipeline.ray_executor import run_on_ray  # ray: an optional extra

        if recipe.jobs > 1:
            log.info(
                "jobs: %d not used with executor: ray (the cluster's CPUs decide)", recipe.jobs
            )

        results = run_on_ray(recipe.stages, start, finish, recipe.trainer, recipe.ray)
    elif recipe.jobs > 1:
        results = run_side_by_side(recipe.stages, recipe.jobs, start, finish)
    else:
        results = {}
        for stage in recipe.stages:
            handle, ctx = start(stage, results)
            results[stage.name] = (
                handle if ctx is None else finish(stage, handle, execute(stage, ctx))
            )
    atomic_write_json(
        recipe.run_dir / "run.json", run_record(recipe, list(results.values()), hasher)
    )
    return list(results.values())


def _one_seed_at_a_time(stage: Stage) -> Any:
    """A stage's config with ``parallel_seeds`` 1 under a launch (said in the log): its seeds'
    worker processes would each join the launch's fits. The key keeps the recipe's value,
    which does not change a seed's result."""
    config = stage.config
    if getattr(config, "parallel_seeds", 1) > 1:
        log.info(
            "stage %s: parallel_seeds %d -> 1 under a launch of several processes",
            stage.name,
            config.parallel_seeds,
        )
        config = config.model_copy(update={"parallel_seeds": 1})
    return config
