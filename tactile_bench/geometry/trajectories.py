"""Sliding trajectories as YCB-Slide records them: a DIGIT dragged over an object's surface.

YCB-Slide's simulated logs are geodesic-like paths of fixed length (0.5 m) joining random
waypoints on the mesh, five per object, with the sensor normal to the surface and its poses
corrupted by zero-mean Gaussian noise (0.5 mm, 1 deg); the real logs are 60 s at 30 Hz of
hand-held sliding. We walk the surface (a step along the tangent towards the next waypoint,
projected back onto the surface) and record ``n_frames`` poses evenly spaced in arc length,
i.e. the 30 Hz log subsampled. A hand-held slide also varies its press and speed and drags the
gel (shear), so each frame records its press depth and its sliding velocity in the gel frame.

Poses are 4 x 4 transforms sensor -> object in mm with the sensor frame of
``sensor.mesh_depth``: z is the gel normal pointing INTO the object, x/y the gel's width and
height (image columns/rows). In ``poses`` the gel plane passes through the surface point
pressed by ``press_mm`` (z offset); the dataset builder settles the press exactly on the mesh.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from tactile_bench.errors import TactileBenchError

#: YCB-Slide's simulated pose noise (README: sigma_trans = 0.5 mm, sigma_rot = 1 deg).
NOISE_TRANS_MM = 0.5
NOISE_ROT_DEG = 1.0
#: the real logs: 60 s at 30 Hz, five 0.5 m trajectories per object
LENGTH_MM = 500.0
DURATION_S = 60.0
FRAME_RATE_HZ = 30.0


@dataclass
class Trajectory:
    """One slide: F frames of true and measured (noisy) sensor poses plus what shear needs."""

    object_name: str
    index: int
    poses: np.ndarray  # (F, 4, 4) true sensor -> object, mm
    measured: np.ndarray  # (F, 4, 4) poses as a tracker reports them (YCB-Slide noise)
    press_mm: np.ndarray  # (F,) commanded gel penetration
    velocity_mm_s: np.ndarray  # (F, 2) sliding velocity of the object under the gel, gel x/y
    time_s: np.ndarray  # (F,) time stamps of the (subsampled) 30 Hz log
    arc_mm: np.ndarray  # (F,) arc length along the path

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def length_mm(self) -> float:
        return float(self.arc_mm[-1] - self.arc_mm[0]) if len(self) else 0.0


@dataclass
class Surface:
    """Points and unit outward normals sampled on the exposed surface of an object."""

    points: np.ndarray
    normals: np.ndarray

    def __post_init__(self) -> None:
        if len(self.points) < 10:
            raise TactileBenchError("surface: fewer than 10 exposed points to slide on")
        self.tree = cKDTree(self.points)

    def project(self, p: np.ndarray) -> np.ndarray:
        """Nearest surface sample of each point."""
        return self.points[self.tree.query(p)[1]]

    def normal(self, p: np.ndarray, k: int = 24) -> np.ndarray:
        """Normal averaged over the k nearest samples (~2 mm): a gel does not feel 0.3 mm ribs."""
        _, idx = self.tree.query(p, k=k)
        near = self.normals[idx]  # (N, k, 3); [:, 0] is the nearest sample
        same_side = np.einsum("nkc,nc->nk", near, near[:, 0]) > 0  # thin parts: skip the far face
        n = (near * same_side[..., None]).sum(1)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)


@contextmanager
def _seeded_trimesh_random(seed: int = 0) -> Iterator[None]:
    """Seed trimesh's shared random generator for the duration.

    ``contains_points`` re-casts the rays whose hit counts disagree (grazing an edge) in a
    direction drawn from trimesh's shared, OS-seeded generator, so without this the exposed
    surface (and every trajectory on it) changed from run to run and process to process.
    """
    saved = getattr(trimesh.util, "_RANDOM_DEFAULT", None)
    if saved is None:  # another trimesh version: nothing to seed
        yield
        return
    trimesh.util._RANDOM_DEFAULT = np.random.default_rng(seed)
    try:
        yield
    finally:
        trimesh.util._RANDOM_DEFAULT = saved


def exposed_surface(parts: Sequence[trimesh.Trimesh]) -> Surface:
    """Vertices (and normals) of the parts that are not buried inside another part."""
    pts, nrm = [], []
    for i, part in enumerate(parts):
        keep = np.ones(len(part.vertices), dtype=bool)
        for j, other in enumerate(parts):
            if i == j or not keep.any():
                continue
            lo, hi = other.bounds
            near = keep & np.all((part.vertices > lo) & (part.vertices < hi), axis=1)
            if near.any():
                try:
                    with _seeded_trimesh_random():
                        inside = other.ray.contains_points(part.vertices[near])
                except ImportError:  # trimesh's pure-Python rays need rtree; embreex is optional
                    continue
                keep[np.nonzero(near)[0][inside]] = False
        pts.append(part.vertices[keep])
        nrm.append(part.vertex_normals[keep])
    return Surface(np.concatenate(pts), np.concatenate(nrm))


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Moving average along axis 0 (edges padded), so normals and directions do not jitter."""
    if width <= 1 or len(x) < 3:
        return x
    pad = np.concatenate([np.repeat(x[:1], width, 0), x, np.repeat(x[-1:], width, 0)])
    kernel = np.ones(2 * width + 1) / (2 * width + 1)
    flat = pad.reshape(len(pad), -1)
    out = np.stack([np.convolve(flat[:, c], kernel, mode="same") for c in range(flat.shape[1])], 1)
    return out[width:-width].reshape(x.shape)


def _walk(
    surface: Surface, start: np.ndarray, length_mm: float, step_mm: float, rng: np.random.Generator
) -> np.ndarray:
    """Points every ~step_mm along a surface walk through random waypoints, >= length_mm long."""
    p = surface.project(start[None])[0]
    path, arcs = [p], [0.0]
    target = surface.points[rng.integers(len(surface.points))]
    d = None
    window = 10
    for _ in range(int(6 * length_mm / step_mm)):
        n = surface.normal(p[None])[0]
        to = target - p
        t = to - n * (n @ to)
        if np.linalg.norm(t) < 1e-6:
            t = np.cross(n, rng.normal(size=3))
        t /= np.linalg.norm(t)
        if d is not None:  # keep some momentum: paths are smooth, not zig-zags
            t = 0.7 * t + 0.3 * (d - n * (n @ d))
            t /= np.linalg.norm(t)
        q = surface.project((p + step_mm * t)[None])[0]
        moved = np.linalg.norm(q - p)
        if moved > 1e-9:
            d = (q - p) / moved
            path.append(q)
            arcs.append(arcs[-1] + moved)
            p = q
        if arcs[-1] >= length_mm:
            return np.array(path)
        stuck = len(path) > window and np.linalg.norm(path[-1] - path[-1 - window]) < 2.5 * step_mm
        if stuck or moved <= 1e-9:
            # caught in a crease or ping-ponging between two samples: drop the dithering,
            # head for another waypoint
            if stuck:
                del path[-window:], arcs[-window:]
                p = path[-1]
            d = np.cross(surface.normal(p[None])[0], rng.normal(size=3))
            target = surface.points[rng.integers(len(surface.points))]
        elif np.linalg.norm(target - p) < 3 * step_mm:
            target = surface.points[rng.integers(len(surface.points))]
    raise TactileBenchError(f"trajectory walk stalled after {arcs[-1]:.0f} of {length_mm:.0f} mm")


def _tangent(d: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, float]:
    """``d`` projected onto the plane normal to ``n``, or any direction in it if that
    vanishes, and its length. Where the smoothed path runs along the normal (a turn the
    smoothing cancelled) the sliding direction carries on from the frame before; without
    this the gel frame collapsed (a zero axis, an invalid pose for the renderer)."""
    t = d - n * (d @ n)
    if np.linalg.norm(t) < 1e-6:
        axis = np.eye(3)[int(np.argmin(np.abs(n)))]  # the axis least along n
        t = np.cross(n, axis)
    return t, float(np.linalg.norm(t))


def pose_noise(n: int, trans_mm: float, rot_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 4, 4) right-multiplied noise as in YCB-Slide's sim: zyx Euler deg, translation mm."""
    noise = np.tile(np.eye(4), (n, 1, 1))
    noise[:, :3, :3] = Rotation.from_euler(
        "zyx", rng.normal(0, rot_deg, (n, 3)), degrees=True
    ).as_matrix()
    noise[:, :3, 3] = rng.normal(0, trans_mm, (n, 3))
    return noise


def sliding_trajectories(
    surface: Surface,
    object_name: str,
    n_trajectories: int = 5,
    n_frames: int = 1800,
    length_mm: float = LENGTH_MM,
    duration_s: float = DURATION_S,
    press_mm: tuple[float, float] = (0.4, 1.2),
    noise_trans_mm: float = NOISE_TRANS_MM,
    noise_rot_deg: float = NOISE_ROT_DEG,
    tilt_deg: float = 2.0,
    seed: int = 0,
) -> list[Trajectory]:
    """``n_trajectories`` slides of ``length_mm`` over ``surface``, ``n_frames`` poses each.

    Defaults follow YCB-Slide (5 x 0.5 m, 1800 frames = 60 s at 30 Hz). The press wanders
    smoothly within ``press_mm``, the speed around ``length_mm / duration_s`` (+-40 %), the
    gel's yaw about its normal drifts around a random heading, the gel tilts up to
    ``tilt_deg`` off the normal (hand-held), and ``measured`` adds YCB-Slide's pose noise.
    """
    if n_trajectories < 1 or n_frames < 2 or length_mm <= 0 or duration_s <= 0:
        raise TactileBenchError(
            "trajectories: need >= 1 trajectory, >= 2 frames, positive length/time"
        )
    lo, hi = press_mm
    if not 0 <= lo <= hi:
        raise TactileBenchError(f"trajectories: bad press range {press_mm}")
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_trajectories):
        s, pos, normal, direc = _slide_path(surface, length_mm, n_frames, rng)
        rot = _gel_rotations(normal, direc, s, tilt_deg, rng)
        press = _press_depths(s, lo, hi, rng)
        poses = np.tile(np.eye(4), (n_frames, 1, 1))
        poses[:, :3, :3] = rot
        poses[:, :3, 3] = pos + rot[:, :, 2] * press[:, None]
        time_s, velocity = _times_and_velocity(s, direc, rot, length_mm, duration_s, rng)
        measured = poses @ pose_noise(n_frames, noise_trans_mm, noise_rot_deg, rng)
        out.append(
            Trajectory(
                object_name,
                k,
                poses,
                measured,
                press.astype(np.float32),
                velocity.astype(np.float32),
                time_s,
                s,
            )
        )
    return out


def _slide_path(
    surface: Surface, length_mm: float, n_frames: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A walk from a random surface point at ``n_frames`` even arc lengths: (arc length,
    position, smoothed normal, unit sliding direction), all but the first (n, 3)."""
    step = 1.0
    start = surface.points[rng.integers(len(surface.points))]
    path = _walk(surface, start, length_mm, step, rng)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s_path = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, length_mm, n_frames)
    pos = np.stack([np.interp(s, s_path, path[:, c]) for c in range(3)], 1)
    # smoothed normal and sliding direction (over ~3 mm of path)
    width = max(1, int(round(3.0 / max(length_mm / n_frames, 1e-9))))
    raw = surface.normal(pos)
    normal = _smooth(raw, width)
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(norm > 0.5, normal / np.maximum(norm, 1e-9), raw)
    dense_dir = np.gradient(path, axis=0)
    direc = np.stack([np.interp(s, s_path, dense_dir[:, c]) for c in range(3)], 1)
    direc = _smooth(direc, width)
    direc -= normal * np.einsum("ij,ij->i", direc, normal)[:, None]
    length = np.linalg.norm(direc, axis=1, keepdims=True)
    for i in np.nonzero(length[:, 0] < 1e-6)[0]:
        direc[i], length[i] = _tangent(direc[i - 1] if i else direc[i], normal[i])
    direc /= np.maximum(length, 1e-9)
    return s, pos, normal, direc


def _gel_rotations(
    normal: np.ndarray, direc: np.ndarray, s: np.ndarray, tilt_deg: float, rng: np.random.Generator
) -> np.ndarray:
    """(n, 3, 3) gel frames: z into the object, y drifting about a heading, a hand's tilt."""
    # gel frame: z into the object; y at a drifting angle psi to the sliding direction
    z = -normal
    side = np.cross(z, direc)
    psi = rng.uniform(0, 2 * np.pi) + np.radians(20) * np.sin(
        2 * np.pi * s / rng.uniform(80, 200) + rng.uniform(0, 2 * np.pi)
    )
    y = np.cos(psi)[:, None] * direc + np.sin(psi)[:, None] * side
    x = np.cross(y, z)
    rot = np.stack([x, y, z], axis=2)  # columns are the sensor axes in the object frame
    if tilt_deg > 0:
        phase = rng.uniform(0, 2 * np.pi, 2)
        lam = rng.uniform(60, 150, 2)
        tilt = np.stack(
            [np.sin(2 * np.pi * s / lam[i] + phase[i]) for i in range(2)] + [np.zeros_like(s)],
            1,
        )
        rot = rot @ Rotation.from_rotvec(np.radians(tilt_deg) * tilt).as_matrix()
    return rot


def _press_depths(s: np.ndarray, lo: float, hi: float, rng: np.random.Generator) -> np.ndarray:
    """Press depth at each frame: two sine waves of random phase, wandering in [lo, hi]."""
    lam_p = rng.uniform(40, 120)
    wave = (
        0.5
        + 0.35 * np.sin(2 * np.pi * s / lam_p + rng.uniform(0, 2 * np.pi))
        + 0.15 * np.sin(2 * np.pi * s / (lam_p / 3.1) + rng.uniform(0, 2 * np.pi))
    )
    return lo + (hi - lo) * np.clip(wave, 0, 1)


def _times_and_velocity(
    s: np.ndarray,
    direc: np.ndarray,
    rot: np.ndarray,
    length_mm: float,
    duration_s: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Frame times at a speed +-40 % about the mean, and the object's velocity in gel x, y."""
    mean_speed = length_mm / duration_s
    speed = mean_speed * (
        1 + 0.4 * np.sin(2 * np.pi * s / rng.uniform(60, 160) + rng.uniform(0, 2 * np.pi))
    )
    ds = np.diff(s)
    time_s = np.concatenate([[0.0], np.cumsum(ds / ((speed[1:] + speed[:-1]) / 2))])
    time_s *= duration_s / time_s[-1]  # the log lasts exactly duration_s
    # the object moves under the gel opposite to the sensor's motion
    vel3 = -direc * speed[:, None] * (time_s[-1] / duration_s)
    velocity = np.einsum("nji,nj->ni", rot[:, :, :2], vel3)
    return time_s, velocity
