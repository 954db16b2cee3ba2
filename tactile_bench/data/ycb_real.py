"""The real YCB-Slide release: its recordings, their gel poses, and (depth, frame) pairs.

``load_ycb_slide_real`` reads the original release (``<root>/real/<object>/dataset_<k>/``,
``<root>/obj_models/<object>/nontextured.stl``) and renders the depth of every frame with
``sensor.mesh_depth``, following YCB-Slide's own pose processing (``process_real_poses``).
``ycb_slide.write_corpus`` stores the pairs as a sharded corpus, split by trajectory.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec, to_depth
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer

from .corpus import CorpusPairs
from .images import SameSize, read_image
from .ycb_processed import released_background

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
) -> CorpusPairs:
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
    gel = gel or GelSpec()
    depths, reals, bgs, bg_idx = [], [], [], []
    meta: dict[str, list[np.ndarray]] = {"object": [], "trajectory": [], "frame": []}
    recordings = find_recordings(root, objects)
    object_names = sorted({r.object_name for r in recordings})
    renderers: dict[str, tuple[MeshDepthRenderer, np.ndarray]] = {}
    for t, rec in enumerate(tqdm(recordings, desc="ycb-slide real", disable=not progress)):
        if rec.object_name not in renderers:
            stl = rec.root / "obj_models" / rec.object_name / "nontextured.stl"
            renderers[rec.object_name] = _object_renderer(stl, gel, mesh_units_m, snap_to_surface)
        renderer, samples = renderers[rec.object_name]
        gel_m, keep = real_gel_poses(
            rec.folder / "synced_data.npy",
            rec.root / "real" / rec.object_name / "alignment.npy",
            rec.object_name,
        )
        frames_dir = rec.folder / "frames"
        frame_files = _frame_files(frames_dir, len(gel_m))
        idx = np.nonzero(keep)[0][::stride]
        same = SameSize(f"frames of {frames_dir}")
        frames, idx = _read_frames(frame_files, idx, gel, same, skipped, frames_dir)
        poses = _pressed_poses(gel_m[idx], samples, snap_to_surface, press_mm)
        height = renderer.render_height(poses)
        depths.append(to_depth(height, gel))
        reals.append(torch.stack(frames))
        bgs.append(_log_background(rec, background, frame_files[0], gel, same))
        bg_idx.append(np.full(len(idx), t))
        meta["object"].append(np.full(len(idx), object_names.index(rec.object_name)))
        meta["trajectory"].append(np.full(len(idx), t))
        meta["frame"].append(idx)
    for renderer, _ in renderers.values():
        renderer.close()
    return CorpusPairs(
        depth=torch.cat(depths),
        real=torch.cat(reals),
        real_background=torch.stack(bgs),
        real_bg_index=torch.from_numpy(np.concatenate(bg_idx)),
        meta={k: np.concatenate(v).astype(np.int64) for k, v in meta.items()},
    )


def _object_renderer(
    stl: Path, gel: GelSpec, mesh_units_m: bool | None, snap_to_surface: bool
) -> tuple[MeshDepthRenderer, np.ndarray]:
    """A log's mesh, checked and in mm: its depth renderer and the points poses snap onto."""
    import trimesh

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
        samples = np.vstack([vertices, trimesh.sample.sample_surface(dense, 200_000, seed=0)[0]])
    return renderer, samples


def _frame_files(frames_dir: Path, n_poses: int) -> list[Path]:
    """A log's ``frame_*.jpg`` in order, one a pose: a log out of step is refused, not paired."""
    frame_files = sorted(frames_dir.glob("frame_*.jpg"))
    if not frame_files:
        raise TactileBenchError(f"{frames_dir}: no frame_*.jpg images")
    if len(frame_files) != n_poses:
        raise TactileBenchError(
            f"{frames_dir}: {len(frame_files)} frames but {n_poses} poses in synced_data.npy"
        )
    return frame_files


def _read_frames(
    frame_files: list[Path],
    idx: np.ndarray,
    gel: GelSpec,
    same: SameSize,
    skipped: list[tuple[str, str]] | None,
    frames_dir: Path,
) -> tuple[list[torch.Tensor], np.ndarray]:
    """Frames ``idx`` at S x S and the indices read: bad ones raise, or go to ``skipped``."""
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
    return frames, np.asarray(good, dtype=np.int64)


def _pressed_poses(
    gel_m: np.ndarray, samples: np.ndarray, snap_to_surface: bool, press_mm: float
) -> np.ndarray:
    """YCB-Slide gel poses in our frame and mm, snapped to the surface and pressed in."""
    poses = gel_m @ _FLIP
    poses[:, :3, 3] *= 1000.0
    if snap_to_surface:
        poses[:, :3, 3] = _closest_on_surface(poses[:, :3, 3], samples)
    poses[:, :3, 3] += poses[:, :3, 2] * press_mm
    return poses


def _log_background(
    rec: YcbSlideRecording, background: str, first_frame: Path, gel: GelSpec, same: SameSize
) -> torch.Tensor:
    """The log's no-contact frame, as ``background`` asks: released, first frame or a file."""
    released = released_background(rec.root / "bgs", rec.object_name)
    if background == "first_frame" or (background == "auto" and released is None):
        return read_image(first_frame, gel.size, same)
    if background == "auto":
        return read_image(released, gel.size)  # resized: the original's order too
    return read_image(Path(background), gel.size, same)
