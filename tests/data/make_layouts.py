"""Generate tiny fixtures in the exact layouts of the original releases (nothing downloaded).

- YCB-Slide real (rpl-cmu/YCB-Slide README, ``process_real_poses``): metres, poses as
  [x, y, z, qx, qy, qz, qw] in the tracker frame, the DIGIT pose is its camera 22 mm behind
  the gel along the gel's +z (which points out of the object).
- Tactile-Diffusion braille (carolinahiguera/Tactile-Diffusion ``utils/misc.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

BOX_M = (0.08, 0.06, 0.04)  # a 80 x 60 x 40 mm box standing in for the scanned object


def _pq(tf: np.ndarray) -> np.ndarray:
    return np.concatenate([tf[:, :3, 3], Rotation.from_matrix(tf[:, :3, :3]).as_quat()], 1)


def make_ycb_slide_real(
    root: Path,
    object_name: str = "004_sugar_box",
    n_frames: int = 6,
    datasets: int = 1,
    frame_hw: tuple[int, int] = (320, 240),
) -> dict[str, np.ndarray]:
    """A box mesh (metres) and ``datasets`` logs whose gel slides flat over its top face.

    Returns the gel positions (object frame, mm) the logs encode, for the tests to check.
    """
    obj_dir = root / "obj_models" / object_name
    obj_dir.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=BOX_M).export(obj_dir / "nontextured.stl")
    real = root / "real" / object_name
    real.mkdir(parents=True, exist_ok=True)
    alignment = np.eye(4)
    alignment[:3, 3] = [0.001, -0.002, 0.0]
    np.save(real / "alignment.npy", alignment)
    rng = np.random.default_rng(0)
    obj_pose = np.eye(4)
    obj_pose[:3, :3] = Rotation.from_euler("zyx", [30, 5, -10], degrees=True).as_matrix()
    obj_pose[:3, 3] = [0.3, -0.1, 0.8]
    gel_xy = np.stack([np.linspace(-0.01, 0.01, n_frames), np.linspace(0.005, -0.005, n_frames)], 1)
    for k in range(datasets):
        gel = np.tile(np.eye(4), (n_frames, 1, 1))
        gel[:, :3, :3] = Rotation.from_euler(
            "z", rng.uniform(-40, 40, (n_frames, 1)), degrees=True
        ).as_matrix()
        gel[:, :2, 3] = gel_xy
        gel[:, 2, 3] = BOX_M[2] / 2  # on the top face; +z of the gel frame points out (up)
        gel[:, :3, 3] -= alignment[:3, 3]  # the loader adds the alignment back
        cam = gel.copy()
        cam[:, :3, 3] += cam[:, :3, 2] * 0.022
        digit = obj_pose[None] @ cam
        objs = np.repeat(obj_pose[None], n_frames, 0)
        folder = real / f"dataset_{k}"
        (folder / "frames").mkdir(parents=True, exist_ok=True)
        np.save(
            folder / "synced_data.npy",
            {
                "poses": {"DIGIT": _pq(digit), object_name: _pq(objs)},
                "timestamps": np.arange(n_frames) / 30.0,
            },
        )
        for i in range(n_frames):
            img = rng.integers(0, 256, (*frame_hw, 3), dtype=np.uint8)
            Image.fromarray(img).save(folder / "frames" / f"frame_{i:07d}.jpg")
    return {"gel_xy_mm": gel_xy * 1000}


def make_braille_layout(
    root: Path,
    letters: tuple[str, ...] = ("a", "b", "#"),
    per_letter: int = 3,
    level: int = 20,
    size_hw: tuple[int, int] = (320, 240),
) -> None:
    """``braille/{real_fine_tuning/{color,mask},real/color,bgs}`` with ``per_letter`` images.

    Every mask is a flat grey ``level`` (so the depth is level * 0.03 mm everywhere).
    """
    rng = np.random.default_rng(1)
    split = {}
    for letter in letters:
        names = [f"{letter}_{i}.png" for i in range(per_letter)]
        for sub in ("real_fine_tuning/color", "real_fine_tuning/mask", "real/color"):
            (root / sub / letter).mkdir(parents=True, exist_ok=True)
        for name in names:
            img = rng.integers(0, 256, (*size_hw, 3), dtype=np.uint8)
            Image.fromarray(img).save(root / "real_fine_tuning/color" / letter / name)
            Image.fromarray(img).save(root / "real/color" / letter / name)
            Image.fromarray(np.full(size_hw, level, np.uint8)).save(
                root / "real_fine_tuning/mask" / letter / name
            )
        split[letter] = {"train": names[:-1], "test": names[-1:]}
    np.save(root / "real_fine_tuning" / "files_train_test.npy", split)
    (root / "bgs").mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((*size_hw, 3), 128, np.uint8)).save(root / "bgs" / "bg_10044.png")
