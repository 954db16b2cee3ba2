"""Building the YCB-Slide stand-in corpus in worker processes, one object (or part) a job.

Each 64-frame chunk of a trajectory depends only on the object's seed, the trajectory and
the chunk (``ycb_frames.chunk_generator``), so objects, and the chunks of one object when
there are fewer objects than workers, can be built in any order and in any process with the
same corpus; a trajectory split over jobs is joined by the caller. Ray casting holds the GIL
(``embreex``), so processes, not threads, are what puts both cores to work. Workers are
spawned (``tactile_bench.pools``) for one build and stopped when it ends, and run torch on
one thread each.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Iterator
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.geometry.objects import object_parts
from tactile_bench.geometry.trajectories import exposed_surface, sliding_trajectories
from tactile_bench.pools import cancel_pending, one_thread_worker, spawned_pool
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import active_timer, run_timed, timed_span

from .corpus import CorpusPairs
from .pixels import to_uint8
from .ycb_frames import (
    TRAJECTORY_CHUNK,
    StandinConfig,
    SurfaceSensor,
    trajectory_chunks,
    trajectory_pairs,
)

#: a part of one trajectory: (trajectory, first chunk, stop chunk), ``TRAJECTORY_CHUNK``s
Piece = tuple[int, int, int]


@dataclass
class ObjectJob:
    """The trajectory pieces ``todo`` of one object: everything a worker process needs."""

    name: str
    index: int
    config: StandinConfig
    gel: GelSpec
    sim_optics: SimOptics
    sim_bg: torch.Tensor
    real_sensor: SurfaceSensor
    real_bg: torch.Tensor
    root: Path
    todo: list[Piece]
    timing: bool = False

    @property
    def object_seed(self) -> int:
        return self.config.seed * 1000 + self.index


@dataclass
class Built:
    """What a job made: {trajectory: pairs} of the shards it wrote, and the pairs of the
    pieces of trajectories split over several jobs, for the caller to join
    (``write_shard``)."""

    written: dict[int, int]
    pieces: dict[Piece, dict[str, Any]]


def write_shard(job: ObjectJob, k: int, pieces: list[dict[str, Any]]) -> int:
    """Write trajectory ``k``'s shard from its pieces (in frame order); returns its pairs.

    A short trajectory (a small corpus has two frames a trajectory) can have no frame the
    sensor reaches without colliding: its shard holds no pairs, and the manifest says so,
    rather than the whole build failing on it."""
    out = {key: _cat([p[key] for p in pieces]) for key in pieces[0]}
    n = len(out["frame"])
    with timed_span("io"):
        CorpusPairs(
            depth=out["depth"],
            real=out["real"],
            real_background=job.real_bg,
            real_bg_index=torch.zeros(n, dtype=torch.int64),
            sim=out["sim"],
            sim_background=to_uint8(job.sim_bg),
            meta={
                "object": np.full(n, job.index, dtype=np.int64),
                "trajectory": np.full(n, job.index * job.config.n_trajectories + k, dtype=np.int64),
                "frame": out["frame"].astype(np.int64),
                "press_mm": out["press_mm"],
                "velocity_mm_s": out["velocity_mm_s"],
                "time_s": out["time_s"],
                "pose": out["poses"].astype(np.float32),
            },
        ).save_shard(job.root / f"shards/{job.name}_{k}.npz")
    return n


def _cat(parts: list[Any]) -> Any:
    return torch.cat(parts) if isinstance(parts[0], torch.Tensor) else np.concatenate(parts)


def build_object(job: ObjectJob) -> Built:
    """Build the pieces ``job.todo``: whole trajectories are written as shards here, parts
    of trajectories are returned to be joined with the rest.

    Everything here depends only on the object's seed, the trajectory index and the chunk,
    so objects and chunks can be built in any order and in any process with the same result.
    """
    import trimesh

    config, gel, name = job.config, job.gel, job.name
    obj_seed = job.object_seed
    with timed_span("objects"):
        parts = object_parts(name, obj_seed)
    with timed_span("surface"):
        surface = exposed_surface(parts)
    with timed_span("trajectories"):
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
    with timed_span("mesh_bvh"):
        renderer = MeshDepthRenderer.from_trimesh(trimesh.util.concatenate(parts), gel)
    built = Built({}, {})
    whole = trajectory_chunks(config.frames_per_trajectory)
    try:
        for k, first, stop in job.todo:
            out = trajectory_pairs(
                renderer,
                trajs[k],
                gel,
                job.sim_optics,
                job.sim_bg,
                job.real_sensor,
                obj_seed,
                range(first, stop),
            )
            if (first, stop) == (0, whole):
                built.written[k] = write_shard(job, k, [out])
            else:
                built.pieces[(k, first, stop)] = out
    finally:
        renderer.close()
    return built


def _build_object_timed(job: ObjectJob) -> tuple[Built, dict | None]:
    """``build_object`` in a worker process, with its span times when the parent times."""
    return run_timed(build_object, job) if job.timing else (build_object(job), None)


def split_jobs(jobs: list[ObjectJob], workers: int) -> list[ObjectJob]:
    """Fewer objects than workers: split each object's chunks into groups of about equal
    frames (each group pays the object's set-up again, in its own process) so every
    worker has as much work (5 trajectories over 2 workers: 2.5 each, not 3 and 2)."""
    if len(jobs) >= workers:
        return jobs
    per_object = -(-workers // len(jobs))
    out = []
    for job in jobs:
        frames = job.config.frames_per_trajectory
        units = [  # (trajectory, chunk, frames in it)
            (k, c, min(TRAJECTORY_CHUNK, frames - c * TRAJECTORY_CHUNK))
            for k, first, stop in job.todo
            for c in range(first, stop)
        ]
        out += _groups(job, units, min(per_object, len(units)))
    return out


def _groups(job: ObjectJob, units: list[tuple[int, int, int]], groups: int) -> list[ObjectJob]:
    """``job`` cut into ``groups`` jobs of consecutive chunks with about equal frames."""
    total = sum(u[2] for u in units)
    bounds = [round(total * g / groups) for g in range(1, groups + 1)]
    cut: list[list[tuple[int, int]]] = [[] for _ in range(groups)]
    done = 0
    for k, c, size in units:
        # the chunk goes to the group its middle frame falls in
        g = next(i for i, b in enumerate(bounds) if done + size / 2 <= b)
        cut[g].append((k, c))
        done += size
    jobs = []
    for chunks in cut:
        pieces: list[Piece] = []
        for k, c in chunks:
            if pieces and pieces[-1][0] == k and pieces[-1][2] == c:
                pieces[-1] = (k, pieces[-1][1], c + 1)
            else:
                pieces.append((k, c, c + 1))
        if pieces:
            jobs.append(dataclasses.replace(job, todo=pieces))
    return jobs


def run_jobs(jobs: list[ObjectJob], workers: int) -> Iterator[tuple[ObjectJob, Built]]:
    """Run the object jobs, in this process or spread over ``workers`` processes; yields
    each (job, what it built) as it finishes.

    Each object, trajectory and chunk is independent (own seeds), so the corpus is the same
    either way; ray casting holds the GIL, so processes (not threads) are what puts both
    cores to work. Workers run torch on one thread each.
    """
    if workers > 1:
        jobs = split_jobs(jobs, workers)
    workers = min(workers, len(jobs))
    if workers <= 1:
        for job in jobs:
            yield job, build_object(job)
        return
    timer = active_timer()
    for job in jobs:
        job.timing = timer is not None
    left = list(jobs)
    try:
        with spawned_pool(workers, initializer=one_thread_worker) as pool:
            futures = {pool.submit(_build_object_timed, job): job for job in jobs}
            try:
                for future in as_completed(futures):
                    built, times = future.result()
                    job = futures[future]
                    left.remove(job)
                    if timer is not None and times is not None:
                        timer.merge_times(times)
                    yield job, built
            finally:  # an error or an interrupt: do not leave the pool busy with the rest
                cancel_pending(futures)
    except BrokenProcessPool:
        # e.g. a script without ``if __name__ == "__main__":`` (spawned workers re-run it)
        warnings.warn(
            "ycb-slide stand-in: worker processes failed to start; building in this process",
            RuntimeWarning,
            stacklevel=3,
        )
        for job in left:
            yield job, build_object(job)
