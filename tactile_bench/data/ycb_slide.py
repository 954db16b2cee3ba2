"""The pretraining corpus: a YCB-Slide stand-in we build, and a loader for the real release.

The paper pretrains its diffusion model on YCB-Slide: a DIGIT slid by hand over ten YCB
objects (five 60 s logs at 30 Hz each, 180k frames), every frame paired with TACTO's depth
rendered at the tracked pose. Without the release we build the same kind of data from
procedural stand-ins of the objects (``geometry.objects``), YCB-Slide-like trajectories
(``geometry.trajectories``) and the surrogate DIGIT:

- the "real" image is the surrogate rendered at the TRUE pose, pressed to the frame's
  press depth (the press is settled on the mesh, like force control would);
- the sim depth (and the sim image) is rendered at the MEASURED pose (YCB-Slide's tracking
  noise, 0.5 mm / 1 deg) settled to the same press, as Tactile-Diffusion snaps the tracked
  gel to the surface and presses it by a fixed depth: the pairs carry the misalignment the
  paper names as its main residual.

Adjacent frames of a log are near duplicates, so the train/test split is BY TRAJECTORY.
The default size (8,000 pairs) is sized for the CPU pretraining budget; 180,000 is the paper's.

The real release is read by ``ycb_real.load_ycb_slide_real``; ``write_corpus`` here stores
its pairs as a corpus sharded and split like the stand-in.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.objects import OBJECTS
from tactile_bench.io import atomic_write_json, file_sha256, json_sha256
from tactile_bench.sensor.background import sim_background as default_sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.sensor.timing import timed_span

from .corpus import FORMAT, CorpusPairs, read_manifest, write_backgrounds
from .pixels import to_uint8
from .ycb_frames import (
    DEFAULT_PAIRS,
    PAPER_PAIRS,
    TRAJECTORY_CHUNK,
    StandinConfig,
    SurfaceSensor,
    settle_press,
    trajectory_chunks,
)
from .ycb_workers import ObjectJob, run_jobs, write_shard

log = logging.getLogger("tactile_bench")


def build_ycb_slide_standin(
    out_dir: str | os.PathLike,
    n_pairs: int = DEFAULT_PAIRS,
    *,
    gel: GelSpec | None = None,
    sim_optics: SimOptics | None = None,
    sim_background: torch.Tensor | None = None,
    real_sensor: SurfaceSensor | None = None,
    seed: int = 0,
    objects: Sequence[str] | None = None,
    config: StandinConfig | None = None,
    progress: bool = True,
    workers: int | None = None,
) -> dict[str, Any]:
    """Write the stand-in corpus under ``out_dir`` and return its manifest.

    One shard per trajectory (``shards/<object>_<k>.npz``), ``backgrounds.npz`` and
    ``manifest.json`` (written last). A rerun with the same settings reuses the shards
    already on disk, so a killed build resumes; other settings start over. Defaults: the
    64 x 64 gel, ``SimOptics()`` over ``sim_background(size)``, the surrogate DIGIT's
    ``digit`` profile. Read it back with ``data.corpus.load_pairs(out_dir, split)``.
    Objects are built in ``workers`` processes (default: ``torch.get_num_threads()``, so
    ``--threads 2`` uses both cores); the corpus does not depend on it.
    """
    workers = torch.get_num_threads() if workers is None else workers

    if real_sensor is None:
        real_sensor = SurrogateDigit.from_profile("digit")
    gel = gel or GelSpec()
    sim_optics = sim_optics or SimOptics()
    if config is None:
        config = StandinConfig(
            n_pairs=n_pairs,
            seed=seed,
            objects=tuple(objects) if objects is not None else tuple(OBJECTS),
        )
    sim_bg = default_sim_background(gel.size) if sim_background is None else sim_background
    sim_bg = to_uint8(sim_bg).float()
    real_bg = to_uint8(real_sensor.background(gel))
    root = Path(out_dir)
    key = _corpus_key(config, gel, sim_optics, sim_bg, real_bg, real_sensor)
    finished = _finished_corpus(root, key)
    if finished is not None:
        return finished
    partial_key_file = root / ".building"
    resumable = partial_key_file.exists() and partial_key_file.read_text() == key
    root.mkdir(parents=True, exist_ok=True)
    partial_key_file.write_text(key)
    write_backgrounds(root, real_bg, sim_bg)

    n_frames = config.frames_per_trajectory
    total = len(config.objects) * config.n_trajectories * n_frames
    jobs = _jobs_to_do(config, gel, sim_optics, sim_bg, real_sensor, real_bg, root, resumable)
    started = time.perf_counter()
    bar = tqdm(total=total, desc="ycb-slide stand-in", unit="pair", disable=not progress)
    n_todo = sum(len(j.todo) for j in jobs)
    bar.update(n_frames * (len(config.objects) * config.n_trajectories - n_todo))  # on disk
    done = _build_shards(jobs, workers, bar, n_frames)
    with timed_span("io"):
        shards = _shard_records(root, config)
    bar.close()
    elapsed = time.perf_counter() - started
    manifest = _manifest(key, config, gel, shards, total)
    # the rate is logged, not written: the manifest is a stage output whose hash keys every
    # stage downstream, so a timing in it would make an identical corpus look new
    if done:
        log.info(
            "ycb-slide stand-in: %d pairs in %.1f s (%.1f pairs/s)", done, elapsed, done / elapsed
        )
    atomic_write_json(root / "manifest.json", manifest)
    partial_key_file.unlink(missing_ok=True)
    return manifest


def _manifest(
    key: str, config: StandinConfig, gel: GelSpec, shards: list[dict[str, Any]], total: int
) -> dict[str, Any]:
    """What ``load_pairs`` reads back: the settings, the shards and the pair counts, as JSON
    types (tuples as lists, as a reload returns them)."""
    manifest = {
        "format": FORMAT,
        "kind": "ycb_slide_standin",
        "key": key,
        "config": asdict(config),
        "gel": asdict(gel),
        "objects": list(config.objects),
        "shards": shards,
        "n_train": sum(s["n"] for s in shards if s["split"] == "train"),
        "n_test": sum(s["n"] for s in shards if s["split"] == "test"),
        "meta_object_names": list(config.objects),
        "frames_dropped": total - sum(s["n"] for s in shards),  # sensor would collide
    }
    return json.loads(json.dumps(manifest))


def _corpus_key(
    config: StandinConfig,
    gel: GelSpec,
    sim_optics: SimOptics,
    sim_bg: torch.Tensor,
    real_bg: torch.Tensor,
    real_sensor: SurfaceSensor,
) -> str:
    """Everything the corpus depends on, hashed: what is on disk is reused only on a match."""
    return json_sha256(
        {
            "config": asdict(config),
            "gel": asdict(gel),
            "sim_optics": asdict(sim_optics),
            "sim_bg": float(sim_bg.sum()),
            "real_bg": int(real_bg.long().sum()),
            "sensor": repr(real_sensor),
            "randomness": "per chunk",  # chunk_generator; corpora seeded per trajectory rebuild
        }
    )


def _finished_corpus(root: Path, key: str) -> dict[str, Any] | None:
    """The manifest of a complete corpus with this key already at ``root``: nothing to build."""
    if (root / "manifest.json").exists():
        try:
            old = read_manifest(root)
            if old.get("key") == key and all((root / s["file"]).exists() for s in old["shards"]):
                return old
        except TactileBenchError:
            pass
    return None


def _jobs_to_do(
    config: StandinConfig,
    gel: GelSpec,
    sim_optics: SimOptics,
    sim_bg: torch.Tensor,
    real_sensor: SurfaceSensor,
    real_bg: torch.Tensor,
    root: Path,
    resumable: bool,
) -> list[ObjectJob]:
    """One job an object, of its whole trajectories not on disk: a resumed build skips those."""
    whole = trajectory_chunks(config.frames_per_trajectory)
    jobs = []
    for oi, name in enumerate(config.objects):
        todo = [
            (k, 0, whole)
            for k in range(config.n_trajectories)
            if not (resumable and (root / f"shards/{name}_{k}.npz").exists())
        ]
        if todo:
            jobs.append(
                ObjectJob(
                    name, oi, config, gel, sim_optics, sim_bg, real_sensor, real_bg, root, todo
                )
            )
    return jobs


def _build_shards(jobs: list[ObjectJob], workers: int, bar: tqdm, n_frames: int) -> int:
    """Run the jobs, joining trajectories built in pieces into their shards; returns pairs."""
    whole = trajectory_chunks(n_frames)
    done = 0
    # trajectories built in pieces: (object, trajectory) -> {(first, stop chunk): pairs}
    split: dict[tuple[int, int], dict[tuple[int, int], dict]] = {}
    for job, built in run_jobs(jobs, workers):
        done += sum(built.written.values())
        bar.update(n_frames * len(built.written))
        for (k, first, stop), pairs in built.pieces.items():
            parts = split.setdefault((job.index, k), {})
            parts[first, stop] = pairs
            bar.update(min(stop * TRAJECTORY_CHUNK, n_frames) - first * TRAJECTORY_CHUNK)
            if sum(b - a for a, b in parts) == whole:  # all here: join them in order
                done += write_shard(job, k, [parts[p] for p in sorted(parts)])
                del split[(job.index, k)]
    return done


def _shard_records(root: Path, config: StandinConfig) -> list[dict[str, Any]]:
    """Each shard's file, object, trajectory, split, pairs and checksum, as the manifest lists."""
    shards = []
    for oi, name in enumerate(config.objects):
        rng = np.random.default_rng([config.seed, oi])
        test = set(
            rng.choice(config.n_trajectories, config.test_trajectories, replace=False).tolist()
        )
        for k in range(config.n_trajectories):
            rel = f"shards/{name}_{k}.npz"
            path = root / rel
            with np.load(path) as z:
                n_kept = len(z["real_bg_index"])
            shards.append(
                {
                    "file": rel,
                    "object": name,
                    "trajectory": k,
                    "split": "test" if k in test else "train",
                    "n": n_kept,
                    "sha256": file_sha256(path),
                }
            )
    return shards


def iter_shards(root: str | os.PathLike) -> Iterator[dict[str, Any]]:
    """The shard records of a built corpus (for tools that stream instead of loading)."""
    yield from read_manifest(root)["shards"]


__all__ = [
    "DEFAULT_PAIRS",
    "PAPER_PAIRS",
    "StandinConfig",
    "build_ycb_slide_standin",
    "iter_shards",
    "settle_press",
    "write_corpus",
]


def write_corpus(
    pairs: CorpusPairs,
    out_dir: str | os.PathLike,
    test_per_object: int = 1,
    kind: str = "ycb_slide",
    test_mask: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write loaded pairs (e.g. ``load_ycb_slide_real``) as a sharded corpus, split by
    trajectory exactly like the stand-in: the last ``test_per_object`` recordings of each
    object are the test split, so adjacent frames never straddle train and test.

    ``test_mask`` (one bool a pair): a split of the data's own instead (Tactile-Diffusion's
    processed YCB-Slide copy lists test frames per log); each log then has a train shard and
    a test shard.
    """
    root = Path(out_dir)
    (root / "shards").mkdir(parents=True, exist_ok=True)
    for key in ("object", "trajectory"):
        if key not in pairs.meta:
            raise TactileBenchError(f"write_corpus: pairs lack the {key!r} metadata to split on")
    write_backgrounds(root, pairs.real_background, pairs.sim_background)
    objects, trajectories = pairs.meta["object"], pairs.meta["trajectory"]
    shards = []

    def shard(where: np.ndarray, rel: str, obj: int, t: int, split: str) -> None:
        idx = torch.from_numpy(np.flatnonzero(where))
        if not len(idx):
            return
        path = pairs.subset(idx).save_shard(root / rel)
        shards.append(
            {
                "file": rel,
                "object": obj,
                "trajectory": t,
                "split": split,
                "n": len(idx),
                "sha256": file_sha256(path),
            }
        )

    for obj in np.unique(objects):
        mine = np.unique(trajectories[objects == obj])
        test = set(mine[len(mine) - test_per_object :].tolist()) if len(mine) > 1 else set()
        for t in mine:
            here = (objects == obj) & (trajectories == t)
            if test_mask is None:
                split = "test" if int(t) in test else "train"
                shard(here, f"shards/{int(obj)}_{int(t)}.npz", int(obj), int(t), split)
            else:
                for split, flag in (("train", False), ("test", True)):
                    rel = f"shards/{int(obj)}_{int(t)}_{split}.npz"
                    shard(
                        here & (np.asarray(test_mask, bool) == flag), rel, int(obj), int(t), split
                    )
    manifest = {
        "format": FORMAT,
        "kind": kind,
        "shards": shards,
        "n_train": sum(s["n"] for s in shards if s["split"] == "train"),
        "n_test": sum(s["n"] for s in shards if s["split"] == "test"),
    }
    atomic_write_json(root / "manifest.json", manifest)
    return manifest
