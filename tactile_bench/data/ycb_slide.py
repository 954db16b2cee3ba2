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

``load_ycb_slide_real`` reads the original release (``<root>/real/<object>/dataset_<k>/``,
``<root>/obj_models/<object>/nontextured.stl``) and renders the depth of every frame with
``sensor.mesh_depth``, following YCB-Slide's own pose processing (``process_real_poses``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.objects import OBJECTS
from tactile_bench.io import atomic_write_json, file_sha256, json_sha256
from tactile_bench.sensor.background import sim_background as default_sim_background
from tactile_bench.sensor.depth import GelSpec, to_depth
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.sensor.timing import stage as timed

from .images import SameSize, read_image
from .pairs import FORMAT, PairSet, read_manifest, write_backgrounds
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
from .ycb_processed import released_background
from .ycb_workers import ObjectJob, run_jobs, write_shard


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
    ``digit`` profile. Read it back with ``data.pairs.load_pairs(out_dir, split)``.
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
    key = json_sha256(
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
    old_key = None
    if (root / "manifest.json").exists():
        try:
            old = read_manifest(root)
            old_key = old.get("key")
            if old_key == key and all((root / s["file"]).exists() for s in old["shards"]):
                return old
        except TactileBenchError:
            pass
    partial_key_file = root / ".building"
    resumable = partial_key_file.exists() and partial_key_file.read_text() == key
    root.mkdir(parents=True, exist_ok=True)
    partial_key_file.write_text(key)
    write_backgrounds(root, real_bg, sim_bg)

    n_frames = config.frames_per_trajectory
    whole = trajectory_chunks(n_frames)
    total = len(config.objects) * config.n_trajectories * n_frames
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
    done, started = 0, time.perf_counter()
    bar = tqdm(total=total, desc="ycb-slide stand-in", unit="pair", disable=not progress)
    n_todo = sum(len(j.todo) for j in jobs)
    bar.update(n_frames * (len(config.objects) * config.n_trajectories - n_todo))  # on disk
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
    shards = []
    with timed("io"):
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
    bar.close()
    elapsed = time.perf_counter() - started
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
        "pairs_per_s": done / elapsed if done else None,
    }
    manifest = json.loads(json.dumps(manifest))  # tuples -> lists: what a reload returns
    atomic_write_json(root / "manifest.json", manifest)
    partial_key_file.unlink(missing_ok=True)
    return manifest


# ====================================================================== the real release
#: the DIGIT camera sits this far behind the gel (YCB-Slide ``cam2gel(..., cam_dist=0.022)``)
CAM_DIST_M = 0.022


def _quat_tf(pq: np.ndarray, where: str) -> np.ndarray:
    """(N, 7) [x, y, z, qx, qy, qz, qw] -> (N, 4, 4), as YCB-Slide's ``positionquat2tf``."""
    pq = np.asarray(pq, dtype=np.float64)
    if pq.ndim != 2 or pq.shape[1] != 7:
        raise TactileBenchError(f"{where}: expected an (N, 7) pose array, got {pq.shape}")
    if not np.isfinite(pq).all():
        raise TactileBenchError(f"{where}: NaN or infinite poses")
    norms = np.linalg.norm(pq[:, 3:], axis=1)
    if (norms < 1e-9).any():
        raise TactileBenchError(f"{where}: zero quaternion")
    tf = np.tile(np.eye(4), (len(pq), 1, 1))
    tf[:, :3, :3] = Rotation.from_quat(pq[:, 3:] / norms[:, None]).as_matrix()
    tf[:, :3, 3] = pq[:, :3]
    return tf


def jump_mask(poses: np.ndarray) -> np.ndarray:
    """False for mocap jumps: YCB-Slide's ``clean_up_optitrack`` (step > 10x the running mean)."""
    keep = np.ones(len(poses), dtype=bool)
    mags: list[float] = []
    for i in range(1, len(poses)):
        step = np.linalg.inv(poses[i - 1]) @ poses[i]
        mags.append(float(np.linalg.norm(step[:3, 3])))
        if i > 1 and mags[-1] > 10 * (sum(mags) / len(mags)):
            keep[i] = False
    return keep


def real_gel_poses(
    synced_file: Path, alignment_file: Path, object_name: str
) -> tuple[np.ndarray, np.ndarray]:
    """Gel poses relative to the object (N, 4, 4, metres, YCB-Slide's frame) and a keep mask.

    Follows YCB-Slide ``process_real_poses``: object^-1 @ DIGIT, drop mocap jumps, move from
    the camera to the gel (22 mm along -z), add the alignment's translation.
    """
    try:
        data = np.load(synced_file, allow_pickle=True)
        data = data.item() if isinstance(data, np.ndarray) and data.dtype == object else data
    except FileNotFoundError:
        raise TactileBenchError(f"{synced_file}: file not found") from None
    except Exception as exc:  # unpickling arbitrary bytes can raise almost anything
        reason = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise TactileBenchError(
            f"{synced_file}: not a readable synced_data.npy ({reason})"
        ) from None
    try:
        poses = data["poses"]
        digit = _quat_tf(poses["DIGIT"], f"{synced_file}: poses.DIGIT")
        obj = _quat_tf(poses[object_name], f"{synced_file}: poses.{object_name}")
    except (KeyError, TypeError, IndexError) as exc:
        raise TactileBenchError(f"{synced_file}: missing poses entry {exc}") from None
    if len(digit) != len(obj):
        raise TactileBenchError(f"{synced_file}: DIGIT and {object_name} poses differ in length")
    try:
        alignment = np.load(alignment_file, allow_pickle=False)
    except FileNotFoundError:
        raise TactileBenchError(f"{alignment_file}: file not found") from None
    except (OSError, ValueError, EOFError) as exc:
        raise TactileBenchError(f"{alignment_file}: not a readable .npy ({exc})") from None
    shape = getattr(alignment, "shape", None)
    if (
        shape != (4, 4)
        or not np.issubdtype(alignment.dtype, np.number)
        or not np.isfinite(alignment).all()
    ):
        raise TactileBenchError(
            f"{alignment_file}: expected a finite 4 x 4 matrix, got {shape or type(alignment)}"
        )
    rel = np.linalg.inv(obj) @ digit
    keep = jump_mask(rel)
    cam_to_gel = np.eye(4)
    cam_to_gel[2, 3] = -CAM_DIST_M
    gel = rel @ cam_to_gel
    gel[:, :3, 3] += alignment[:3, 3]  # ([I | t] @ A).t = t + A.t: translation only, as YCB-Slide
    return gel, keep


#: YCB-Slide's gel frame has z pointing OUT of the object (towards the camera); ours points in.
_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def _closest_on_surface(points: np.ndarray, samples: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return samples[cKDTree(samples).query(points)[1]]


@dataclass(frozen=True)
class YcbSlideRecording:
    """One real log: ``<root>/real/<object>/dataset_<k>``."""

    root: Path
    object_name: str
    index: int

    @property
    def folder(self) -> Path:
        return self.root / "real" / self.object_name / f"dataset_{self.index}"


def find_recordings(
    root: str | os.PathLike, objects: Sequence[str] | None = None
) -> list[YcbSlideRecording]:
    """Every ``real/<object>/dataset_<k>`` folder under ``root`` (e.g. ``004_sugar_box``)."""
    root = Path(root)
    real = root / "real"
    if not real.is_dir():
        raise TactileBenchError(
            f"{real}: folder not found (expected YCB-Slide's real/<object>/dataset_<k>)"
        )
    names = (
        sorted(p.name for p in real.iterdir() if p.is_dir()) if objects is None else list(objects)
    )
    out = []
    for name in names:
        folder = real / name
        if not folder.is_dir():
            raise TactileBenchError(f"{folder}: folder not found")
        for d in sorted(folder.glob("dataset_*")):
            suffix = d.name.split("_", 1)[1]
            if d.is_dir() and suffix.isdigit():
                out.append(YcbSlideRecording(root, name, int(suffix)))
    if not out:
        raise TactileBenchError(f"{real}: no dataset_<k> recordings found")
    return out


def load_ycb_slide_real(
    root: str | os.PathLike,
    objects: Sequence[str] | None = None,
    gel: GelSpec | None = None,
    press_mm: float = 0.7,
    stride: int = 1,
    background: str = "auto",
    mesh_units_m: bool | None = None,
    snap_to_surface: bool = True,
    progress: bool = False,
    skipped: list[tuple[str, str]] | None = None,
) -> PairSet:
    """(sim depth, real frame) pairs of the YCB-Slide real logs under ``root``.

    For each ``real/<object>/dataset_<k>``: read ``synced_data.npy`` and the object's
    ``alignment.npy``, compute the gel pose relative to ``obj_models/<object>/nontextured.stl``
    as YCB-Slide does, snap it to the closest surface point and press it ``press_mm`` (0.7 mm
    like Tactile-Diffusion's ``render_sensor_trajectory``), render the depth with
    ``sensor.mesh_depth`` and pair it with ``frames/frame_<i:07d>.jpg`` resized to S x S.
    Frames the mocap cleanup drops are skipped; ``stride`` subsamples the 30 Hz log.
    ``background``: ``"auto"`` (default): the released no-contact frame of the object,
    ``<root>/bgs/bg_<i>.jpg`` by Tactile-Diffusion's ``bgs_objects`` map, when present, else
    the log's first frame; ``"first_frame"`` (logs start before the touch); or an image path.
    ``mesh_units_m``: YCB meshes are in metres; ``None`` guesses from the mesh size.
    Every frame is decoded and must be RGB of one size per log. With ``skipped`` (a list),
    unreadable or wrong frames are dropped and recorded in it (file, reason) instead of raising.
    """
    import trimesh

    gel = gel or GelSpec()
    depths, reals, bgs, bg_idx = [], [], [], []
    meta: dict[str, list[np.ndarray]] = {"object": [], "trajectory": [], "frame": []}
    recordings = find_recordings(root, objects)
    object_names = sorted({r.object_name for r in recordings})
    renderers: dict[str, tuple[MeshDepthRenderer, np.ndarray]] = {}
    for t, rec in enumerate(tqdm(recordings, desc="ycb-slide real", disable=not progress)):
        if rec.object_name not in renderers:
            stl = rec.root / "obj_models" / rec.object_name / "nontextured.stl"
            if not stl.exists():
                raise TactileBenchError(f"{stl}: file not found")
            try:
                mesh = trimesh.load(stl, force="mesh")
            except Exception as exc:  # trimesh raises many types on bad files
                raise TactileBenchError(f"{stl}: not a readable mesh ({exc})") from None
            if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
                raise TactileBenchError(f"{stl}: no triangles (unreadable or empty mesh)")
            if not np.isfinite(mesh.vertices).all():
                raise TactileBenchError(f"{stl}: NaN or infinite vertex coordinates")
            in_m = mesh.scale < 5.0 if mesh_units_m is None else mesh_units_m
            vertices = mesh.vertices * (1000.0 if in_m else 1.0)
            renderer = MeshDepthRenderer(vertices, mesh.faces, gel)
            samples = vertices
            if snap_to_surface:
                dense = trimesh.Trimesh(vertices, mesh.faces, process=False)
                samples = np.vstack(
                    [vertices, trimesh.sample.sample_surface(dense, 200_000, seed=0)[0]]
                )
            renderers[rec.object_name] = (renderer, samples)
        renderer, samples = renderers[rec.object_name]
        gel_m, keep = real_gel_poses(
            rec.folder / "synced_data.npy",
            rec.root / "real" / rec.object_name / "alignment.npy",
            rec.object_name,
        )
        frames_dir = rec.folder / "frames"
        frame_files = sorted(frames_dir.glob("frame_*.jpg"))
        if not frame_files:
            raise TactileBenchError(f"{frames_dir}: no frame_*.jpg images")
        if len(frame_files) != len(gel_m):
            raise TactileBenchError(
                f"{frames_dir}: {len(frame_files)} frames but {len(gel_m)} poses in synced_data.npy"
            )
        idx = np.nonzero(keep)[0][::stride]
        same = SameSize(f"frames of {frames_dir}")
        frames, good = [], []
        for i in idx:
            try:
                frames.append(read_image(frame_files[i], gel.size, same))
                good.append(i)
            except TactileBenchError as exc:
                if skipped is None:
                    raise
                skipped.append((str(frame_files[i]), str(exc)))
        if not good:
            raise TactileBenchError(f"{frames_dir}: no readable frames")
        idx = np.asarray(good, dtype=np.int64)
        poses = gel_m[idx] @ _FLIP
        poses[:, :3, 3] *= 1000.0
        if snap_to_surface:
            poses[:, :3, 3] = _closest_on_surface(poses[:, :3, 3], samples)
        poses[:, :3, 3] += poses[:, :3, 2] * press_mm
        height = renderer.render_height(poses)
        depths.append(to_depth(height, gel))
        reals.append(torch.stack(frames))
        released = released_background(rec.root / "bgs", rec.object_name)
        if background == "first_frame" or (background == "auto" and released is None):
            bgs.append(read_image(frame_files[0], gel.size, same))
        elif background == "auto":
            bgs.append(read_image(released, gel.size))  # resized: the original's order too
        else:
            bgs.append(read_image(Path(background), gel.size, same))
        bg_idx.append(np.full(len(idx), t))
        meta["object"].append(np.full(len(idx), object_names.index(rec.object_name)))
        meta["trajectory"].append(np.full(len(idx), t))
        meta["frame"].append(idx)
    for renderer, _ in renderers.values():
        renderer.close()
    return PairSet(
        depth=torch.cat(depths),
        real=torch.cat(reals),
        real_background=torch.stack(bgs),
        real_bg_index=torch.from_numpy(np.concatenate(bg_idx)),
        meta={k: np.concatenate(v).astype(np.int64) for k, v in meta.items()},
    )


def iter_shards(root: str | os.PathLike) -> Iterator[dict[str, Any]]:
    """The shard records of a built corpus (for tools that stream instead of loading)."""
    yield from read_manifest(root)["shards"]


__all__ = [
    "DEFAULT_PAIRS",
    "PAPER_PAIRS",
    "StandinConfig",
    "build_ycb_slide_standin",
    "find_recordings",
    "load_ycb_slide_real",
    "real_gel_poses",
    "settle_press",
]


def write_corpus(
    pairs: PairSet,
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
