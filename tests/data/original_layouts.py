"""Tiny fixtures written to the paths the ORIGINAL code reads, not to what our loaders expect.

Every path below is spelled as in carolinahiguera/Tactile-Diffusion (stored at 80797b8):

- ``tacto_diffusion/utils/misc.py``: ``DIRS_BRAILLE`` (``datasets/braille/real_fine_tuning/
  {color,mask}/<letter>/<f>``, ``datasets/braille/bgs``), ``bgs_letters`` (the 27 letter
  folders ``a``..``z``, ``#``), ``DIRS_YCB`` (``datasets/YCB-Slide/dataset``,
  ``datasets/YCB-Slide/bgs``), ``bgs_objects`` (object -> ``bg_<i>.jpg``) and
  ``get_train_test_idx`` (``np.savez(files_train_test.npz, train=..., test=...)``);
- ``tacto_diffusion/data/dataio_braille.py``: ``bg_10044.png``; the colour frame and the mask
  of a contact share one file name; the mask is read with ``cv2.imread`` (3 channels) and
  converted to grey, each image resized to 64 on its own;
- ``braille_clf/config/config_tacto*.yaml`` and ``braille_clf/data/dataio.py``:
  ``datasets/braille/real/color/<letter>/*`` (test), ``datasets/braille/sim_tacto/color/
  <letter>/*`` (the Sim row), ``bg_11.png`` (sim) and ``bg_10044.png`` (real);
- ``ycb_slide_sim/modules/misc.py`` ``save_hm``: the TACTO heightmap flipped on both axes and
  written as ``frame_%07d.jpg`` in ``frames_depth/``; ``touch_simulator.py`` names the frames.

No ``files_train_test.npy``: ``train_braille.py`` writes it at every run, so a fresh release
has none. The masks are smaller than the frames and some are stored as colour JPEGs (what
``cv2.imwrite`` of a 3-channel array gives): the original reads both.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

BGS_LETTERS = "abcdefghijklmnopqrstuvwxyz#"  # misc.py bgs_letters, in its order
BGS_OBJECTS = {"004_sugar_box": 0, "025_mug": 4}  # two entries of misc.py bgs_objects
FRAME_WH = (48, 64)  # a DIGIT frame is 240 x 320 (w x h); a fifth of it keeps tests fast
MASK_WH = (24, 32)  # save_image writes masks at (240, 320); here half the frame's size


def _frame(rng: np.random.Generator, base: np.ndarray) -> np.ndarray:
    return np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8)


def _mask(level: int, letter_index: int, wh: tuple[int, int]) -> np.ndarray:
    """A press: a bright blob whose position depends on the letter (grey levels 0..level)."""
    w, h = wh
    yy, xx = np.mgrid[0:h, 0:w]
    cx, cy = (letter_index % 5 + 1) * w / 6, (letter_index // 5 % 5 + 1) * h / 6
    blob = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (w / 8) ** 2))
    return np.round(level * blob).astype(np.uint8)


def write_braille_release(datasets: Path, per_letter: int = 10, real_per_letter: int = 1) -> Path:
    """``<datasets>/braille`` as the release holds it; returns that folder.

    ``per_letter`` = 10 is the least for which ``split_braille_dataset(0.2, 0.2)`` keeps a
    training file per letter (int(int(10 * 0.2) * 0.8) = 1).
    """
    rng = np.random.default_rng(24)
    braille = datasets / "braille"
    color = braille / "real_fine_tuning" / "color"
    mask = braille / "real_fine_tuning" / "mask"
    bgs = braille / "bgs"
    bgs.mkdir(parents=True, exist_ok=True)
    w, h = FRAME_WH
    bg_real = np.full((h, w, 3), (150, 120, 110), np.uint8)
    bg_sim = np.full((h, w, 3), (90, 100, 130), np.uint8)
    Image.fromarray(bg_real).save(bgs / "bg_10044.png")
    Image.fromarray(bg_sim).save(bgs / "bg_11.png")
    Image.fromarray(bg_sim[..., ::-1].copy()).save(bgs / "bg_12.png")
    for k, letter in enumerate(BGS_LETTERS):
        for sub in (color / letter, mask / letter):
            sub.mkdir(parents=True, exist_ok=True)
        for i in range(per_letter):
            name = f"{i}.jpg"  # one name for the frame and its mask (dataio_braille.py)
            m = _mask(20 + i, k, MASK_WH)
            if i % 2:  # cv2.imwrite of a 3-channel grey array: a colour JPEG
                Image.fromarray(np.repeat(m[..., None], 3, 2)).save(mask / letter / name)
            else:
                Image.fromarray(m).save(mask / letter / name)
            press = np.asarray(Image.fromarray(m).resize(FRAME_WH, Image.Resampling.BILINEAR))
            frame = bg_real.astype(float) + press[..., None] * np.array([2.0, 1.0, -1.0])
            Image.fromarray(_frame(rng, frame)).save(color / letter / name, quality=95)
        for sub, base in (("real", bg_real), ("sim_tacto", bg_sim)):
            folder = braille / sub / "color" / letter
            folder.mkdir(parents=True, exist_ok=True)
            for i in range(real_per_letter):
                press = np.asarray(
                    Image.fromarray(_mask(24, k, MASK_WH)).resize(
                        FRAME_WH, Image.Resampling.BILINEAR
                    )
                )
                frame = base.astype(float) + press[..., None] * np.array([2.0, 1.0, -1.0])
                Image.fromarray(_frame(rng, frame)).save(folder / f"{letter}_{i}.jpg")
    return braille


def write_ycb_processed(datasets: Path, frames: int = 6, logs: int = 2) -> Path:
    """``<datasets>/YCB-Slide`` as Tactile-Diffusion's pretraining reads it; returns it.

    ``frames/`` are DIGIT frames, ``frames_depth/`` the TACTO heightmaps in pixels of 0.03 mm
    (``pixmm``), flipped on both axes by ``save_hm``; frame 1 of each log is a mocap glitch
    ``touch_simulator.py`` removed from ``frames_depth`` (``idx_remove``).
    """
    rng = np.random.default_rng(5)
    root = datasets / "YCB-Slide"
    (root / "bgs").mkdir(parents=True, exist_ok=True)
    w, h = FRAME_WH
    for obj, bg_id in BGS_OBJECTS.items():
        bg = np.full((h, w, 3), (140 + 10 * bg_id, 120, 100), np.uint8)
        Image.fromarray(bg).save(root / "bgs" / f"bg_{bg_id}.jpg")
        for k in range(logs):
            log = root / "dataset" / obj / f"dataset_{k}"
            (log / "frames").mkdir(parents=True, exist_ok=True)
            (log / "frames_depth").mkdir(parents=True, exist_ok=True)
            names = []
            for i in range(frames):
                name = f"frame_{i:07d}.jpg"
                names.append(name)
                hm = _mask(23, i, FRAME_WH)  # 0.7 mm press = 23 levels of 0.03 mm
                Image.fromarray(_frame(rng, bg.astype(float) + hm[..., None])).save(
                    log / "frames" / name
                )
                if i != 1:  # TACTO's raw map is the frame's rotated 180 deg; save_hm flips it back
                    raw = hm[::-1, ::-1]
                    saved = raw[::-1, ::-1].copy()  # cv2.flip(raw, 0) then cv2.flip(., 1)
                    Image.fromarray(saved).save(log / "frames_depth" / name)
            test = names[-1:]
            np.savez(log / "files_train_test.npz", train=names[:-1], test=test)
    return root


# ---------------------------------------------------------------- YCB-Slide, the orientation
#: Tactile-Diffusion's TACTO camera (``digit_render.py``): cam = gel @ T(z = cam_dist - press)
#: @ fix_transform (``euler2matrix([-90, 0, 90], xyz="zyx", degrees=True)``) @ the camera's zero
#: pose of ``config_digit_shadow.yml`` (orientation [90, 0, -90], "xyz" Euler angles, the
#: renderer's ``euler2matrix``: scipy ``from_euler``). pyrender draws camera +x to the right
#: and camera +y up. ``update_camera_pose_from_matrix`` is taken to compose like TACTO's
#: ``update_camera_pose`` (pose @ camera zero pose): it is not in the stored copies.
def tacto_camera_axes() -> np.ndarray:
    """(3, 3): the TACTO camera's x, y, z axes (columns) in the gel frame."""
    from scipy.spatial.transform import Rotation

    fix = Rotation.from_euler("zyx", [-90, 0, 90], degrees=True).as_matrix()
    zero = Rotation.from_euler("xyz", [90, 0, -90], degrees=True).as_matrix()
    return fix @ zero


def original_frame_depth(
    surface: Callable[[np.ndarray, np.ndarray], np.ndarray],
    wh: tuple[int, int],
    gel_mm: tuple[float, float] = (18.0, 24.0),
) -> np.ndarray:
    """The penetration (mm, h x w) as a real frame shows it, by the original's convention:
    TACTO's map seen by its camera, then ``save_hm``'s flip of both axes.

    ``surface(gx, gy)``: penetration at gel-frame point (mm; YCB-Slide's gel frame, z out of
    the object).
    """
    w, h = wh
    axes = tacto_camera_axes()
    u = (np.arange(w) + 0.5) / w - 0.5
    v = (np.arange(h) + 0.5) / h - 0.5
    cam_x = np.broadcast_to(u[None, :] * gel_mm[0], (h, w))  # columns: camera +x
    cam_y = np.broadcast_to(-v[:, None] * gel_mm[1], (h, w))  # rows: camera -y (image down)
    gx = axes[0, 0] * cam_x + axes[0, 1] * cam_y
    gy = axes[1, 0] * cam_x + axes[1, 1] * cam_y
    raw = surface(gx, gy)  # TACTO's heightmap, as its camera sees it
    return raw[::-1, ::-1].copy()  # save_hm: cv2.flip(., 0), cv2.flip(., 1)


def write_ycb_slide_wedge(
    root: Path,
    object_name: str = "004_sugar_box",
    n_frames: int = 6,
    glitch: int = 3,
    slope: tuple[float, float] = (0.03, -0.02),
    yaw_deg: float = 25.0,
    press_mm: float = 0.7,
) -> dict[str, object]:
    """A YCB-Slide release log (``real/<object>/dataset_0``: ``synced_data.npy``,
    ``frames/frame_%07d.jpg``; ``real/<object>/alignment.npy``; ``obj_models/<object>/
    nontextured.stl`` in metres; ``bgs/bg_<i>.jpg``) over a WEDGE: a box whose top face
    rises by ``slope`` (dz/dx, dz/dy), so each frame's contact is asymmetric.

    Frames are the no-contact frame plus the penetration drawn by ``original_frame_depth``.
    Frame ``glitch`` is a mocap jump (DIGIT 0.4 m off), which ``clean_up_optitrack`` drops
    (it flags a step of more than 10x the running mean, so only after 11 frames).
    """
    import trimesh
    from scipy.spatial.transform import Rotation

    a, b = slope
    lx, ly = 0.08, 0.06
    corners = [(x, y) for x in (-lx / 2, lx / 2) for y in (-ly / 2, ly / 2)]
    points = [(x, y, -0.02) for x, y in corners] + [
        (x, y, 0.02 + a * x + b * y) for x, y in corners
    ]
    obj_dir = root / "obj_models" / object_name
    obj_dir.mkdir(parents=True, exist_ok=True)
    trimesh.convex.convex_hull(np.asarray(points)).export(obj_dir / "nontextured.stl")
    real = root / "real" / object_name
    log = real / "dataset_0"
    (log / "frames").mkdir(parents=True, exist_ok=True)
    np.save(real / "alignment.npy", np.eye(4))
    yaw = np.deg2rad(yaw_deg)
    rot = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    xs = np.linspace(-0.01, 0.01, n_frames)
    gel = np.tile(np.eye(4), (n_frames, 1, 1))
    gel[:, :3, :3] = rot
    gel[:, 0, 3], gel[:, 1, 3] = xs, 0.004
    gel[:, 2, 3] = 0.02 + a * xs + b * 0.004  # on the slanted top, z out of the object
    cam = gel.copy()
    cam[:, :3, 3] += cam[:, :3, 2] * 0.022  # the DIGIT pose is its camera's, 22 mm behind
    cam[glitch, :3, 3] += 0.4
    pq = np.concatenate([cam[:, :3, 3], Rotation.from_matrix(cam[:, :3, :3]).as_quat()], 1)
    obj = np.tile([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], (n_frames, 1))
    np.save(log / "synced_data.npy", {"poses": {"DIGIT": pq, object_name: obj}})
    w, h = FRAME_WH
    bg = np.full((h, w, 3), (120, 110, 100), np.float64)
    (root / "bgs").mkdir(parents=True, exist_ok=True)
    Image.fromarray(bg.astype(np.uint8)).save(root / "bgs" / "bg_0.jpg", quality=95)
    # the surface over gel point (gx, gy) mm, along the gel normal: a planar top, so the same
    # for every frame; the gel centre touches it and is pressed press_mm
    ca, sa = np.cos(yaw), np.sin(yaw)

    def penetration(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        ox, oy = ca * gx - sa * gy, sa * gx + ca * gy  # gel -> object axes (mm)
        return np.maximum(0.0, press_mm + a * ox + b * oy)

    depth = original_frame_depth(penetration, FRAME_WH)
    for i in range(n_frames):
        frame = bg + depth[..., None] * np.array([60.0, 30.0, -40.0])
        Image.fromarray(np.clip(frame, 0, 255).astype(np.uint8)).save(
            log / "frames" / f"frame_{i:07d}.jpg", quality=95
        )
    return {"depth": depth, "glitch": glitch}
