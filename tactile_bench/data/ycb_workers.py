"""Building the YCB-Slide stand-in corpus in worker processes, one object (or part) a job.

Each object's trajectories depend only on the object's seed and their index, so objects can
be built in any order and in any process with the same corpus. Ray casting holds the GIL
(``embreex``), so processes, not threads, are what puts both cores to work. Workers are
spawned (not forked: the parent's OpenMP and Embree thread pools do not survive a fork),
run torch on one thread each, and are kept for later builds (spawning one costs ~2 s).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.geometry.objects import object_parts
from tactile_bench.geometry.trajectories import exposed_surface, sliding_trajectories
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import StageTimer, active_timer
from tactile_bench.sensor.timing import stage as timed

from .pairs import PairSet, to_uint8
from .ycb_slide import StandinConfig, SurfaceSensor, _trajectory_pairs


@dataclass
class ObjectJob:
    """The trajectories ``todo`` of one object: everything a worker process needs."""

    name: str
    index: int
    config: StandinConfig
    gel: GelSpec
    sim_optics: SimOptics
    sim_bg: torch.Tensor
    real_sensor: SurfaceSensor
    real_bg: torch.Tensor
    root: Path
    todo: list[int]
    timing: bool = False


def _build_object(job: ObjectJob) -> dict[int, int]:
    """Build and write the shards of ``job.todo``; returns {trajectory: pairs written}.

    Everything here depends only on the object's seed and the trajectory index, so objects
    can be built in any order and in any process with the same result.
    """
    import trimesh

    config, gel, oi, name = job.config, job.gel, job.index, job.name
    obj_seed = config.seed * 1000 + oi
    with timed("objects"):
        parts = object_parts(name, obj_seed)
    with timed("surface"):
        surface = exposed_surface(parts)
    with timed("trajectories"):
        trajs = sliding_trajectories(
            surface,
            name,
            config.n_trajectories,
            config.frames_per_trajectory,
            length_mm=config.length_mm,
            press_mm=config.press_mm,
            noise_trans_mm=config.noise_trans_mm,
            noise_rot_deg=config.noise_rot_deg,
            tilt_deg=config.tilt_deg,
            seed=obj_seed,
        )
    with timed("mesh_bvh"):
        renderer = MeshDepthRenderer.from_trimesh(trimesh.util.concatenate(parts), gel)
    built = {}
    try:
        for k in job.todo:
            traj = trajs[k]
            gen = torch.Generator().manual_seed(obj_seed * 100 + k)
            out = _trajectory_pairs(
                renderer, traj, gel, job.sim_optics, job.sim_bg, job.real_sensor, gen
            )
            f = out["frame"]
            n = len(f)
            with timed("io"):
                PairSet(
                    depth=out["depth"],
                    real=out["real"],
                    real_background=job.real_bg,
                    real_bg_index=torch.zeros(n, dtype=torch.int64),
                    sim=out["sim"],
                    sim_background=to_uint8(job.sim_bg),
                    meta={
                        "object": np.full(n, oi, dtype=np.int64),
                        "trajectory": np.full(n, oi * config.n_trajectories + k, dtype=np.int64),
                        "frame": f.astype(np.int64),
                        "press_mm": traj.press_mm[f],
                        "velocity_mm_s": traj.velocity_mm_s[f],
                        "time_s": traj.time_s[f].astype(np.float32),
                        "pose": out["poses"].astype(np.float32),
                    },
                ).save_shard(job.root / f"shards/{name}_{k}.npz")
            built[k] = n
    finally:
        renderer.close()
    return built


def _worker_init() -> None:
    torch.set_num_threads(1)  # one process per core: no intra-op threads on top


def _build_object_timed(job: ObjectJob) -> tuple[dict[int, int], dict | None]:
    """``_build_object`` in a worker process, with its stage times when the parent times."""
    if not job.timing:
        return _build_object(job), None
    cpu = time.process_time()
    with StageTimer() as timer:
        built = _build_object(job)
    times = {"wall": dict(timer.wall), "cpu": dict(timer.cpu)}
    return built, {**times, "process_cpu": time.process_time() - cpu}


_POOL: Any = None  # (workers, ProcessPoolExecutor) kept for later builds: spawning costs ~2 s


def _pool(workers: int) -> Any:
    """A process pool of ``workers`` spawned workers, reused across builds in this process.

    Spawned, not forked: the parent's OpenMP and Embree thread pools do not survive a fork.
    Each worker imports the package once (~2 s of CPU), so keeping them pays off from the
    second build on (benchmarks, pipelines with several corpora); shut down at exit.
    """
    global _POOL
    import atexit
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    if _POOL is not None and _POOL[0] == workers and not getattr(_POOL[1], "_broken", False):
        return _POOL[1]
    if _POOL is not None:
        _POOL[1].shutdown(wait=False, cancel_futures=True)
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init)
    if _POOL is None:
        atexit.register(lambda: _POOL is not None and _POOL[1].shutdown(wait=False))
    _POOL = (workers, pool)
    return pool


def _split_jobs(jobs: list[ObjectJob], workers: int) -> list[ObjectJob]:
    """Fewer objects than workers: split each object's trajectories into groups (each
    group pays the object's set-up again, in its own process) so every worker has work."""
    if len(jobs) >= workers:
        return jobs
    per_object = -(-workers // len(jobs))
    out = []
    for job in jobs:
        groups = min(per_object, len(job.todo))
        for g in range(groups):
            out.append(dataclasses.replace(job, todo=job.todo[g::groups]))
    return out


def run_jobs(jobs: list[ObjectJob], workers: int) -> Iterator[dict[int, int]]:
    """Run the object jobs, in this process or spread over ``workers`` processes.

    Each object (and each trajectory) is independent (own seeds), so the corpus is the same
    either way; ray casting holds the GIL, so processes (not threads) are what puts both
    cores to work. Workers run torch on one thread each.
    """
    if workers > 1:
        jobs = _split_jobs(jobs, workers)
    workers = min(workers, len(jobs))
    if workers <= 1:
        for job in jobs:
            yield _build_object(job)
        return
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    timer = active_timer()
    for job in jobs:
        job.timing = timer is not None
    left = list(jobs)
    try:
        pool = _pool(workers)
        futures = {pool.submit(_build_object_timed, job): job for job in jobs}
        try:
            for future in as_completed(futures):
                built, times = future.result()
                left.remove(futures[future])
                if timer is not None and times is not None:
                    timer.merge(times["wall"], times["cpu"], times["process_cpu"])
                yield built
        finally:  # an error or an interrupt: do not leave the pool busy with the rest
            for future in futures:
                future.cancel()
    except BrokenProcessPool:
        # e.g. a script without ``if __name__ == "__main__":`` (spawned workers re-run it)
        warnings.warn(
            "ycb-slide stand-in: worker processes failed to start; building in this process",
            RuntimeWarning,
            stacklevel=3,
        )
        for job in left:
            yield _build_object(job)
