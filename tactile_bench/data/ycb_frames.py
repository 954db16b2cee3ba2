"""The YCB-Slide stand-in's frames: its settings, settling a pose onto the mesh, and one
trajectory chunk's (depth, sim, real) pairs.

Apart from ``ycb_slide`` (the builder) so that the worker processes (``ycb_workers``) and the
builder import it one way: ``ycb_frames`` <- ``ycb_workers`` <- ``ycb_slide``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.objects import OBJECTS
from tactile_bench.geometry.trajectories import Trajectory
from tactile_bench.sensor.depth import GelSpec, to_depth
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import timed_span

from .pixels import to_uint8

DEFAULT_PAIRS = 8000  # CPU budget; the paper's corpus is 180_000 ("paper" preset)
PAPER_PAIRS = 180_000


class SurfaceSensor(Protocol):
    """What the builder needs of the "real" sensor: ``sensor.surrogate.SurrogateDigit``."""

    def background(self, size: int | GelSpec = 64) -> torch.Tensor: ...

    def render_surface(
        self,
        height: torch.Tensor,
        gel: GelSpec | None = None,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor: ...


@dataclass(frozen=True)
class StandinConfig:
    """Everything that decides the corpus' content (hashed into the manifest)."""

    n_pairs: int = DEFAULT_PAIRS
    seed: int = 0
    objects: tuple[str, ...] = tuple(OBJECTS)
    n_trajectories: int = 5
    test_trajectories: int = 1  # per object: 1 of 5 = the paper's 80/20, split by trajectory
    length_mm: float = 500.0
    press_mm: tuple[float, float] = (0.4, 1.2)
    noise_trans_mm: float = 0.5
    noise_rot_deg: float = 1.0
    tilt_deg: float = 2.0

    def __post_init__(self) -> None:
        if self.n_pairs < 1:
            raise TactileBenchError(f"ycb-slide: n_pairs must be >= 1, got {self.n_pairs}")
        unknown = [o for o in self.objects if o not in OBJECTS]
        if unknown or not self.objects:
            raise TactileBenchError(
                f"ycb-slide: unknown objects {unknown}; known: {sorted(OBJECTS)}"
            )
        if not 0 <= self.test_trajectories < self.n_trajectories:
            raise TactileBenchError("ycb-slide: need 0 <= test_trajectories < n_trajectories")

    @property
    def frames_per_trajectory(self) -> int:
        return max(2, -(-self.n_pairs // (len(self.objects) * self.n_trajectories)))


#: pixel stride of ``settle_press``'s peak probe: 1/16 of a frame's rays
PEAK_STEP = 4


def settle_press(
    renderer: MeshDepthRenderer,
    poses: np.ndarray,
    press_mm: np.ndarray,
    passes: int = 2,
    peak_step: int | None = PEAK_STEP,
) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Slide each pose along its z until the deepest gel penetration equals ``press_mm``.

    A rigid shift along the ray direction shifts the whole signed height by the same amount,
    so one render gives the correction; a second pass re-renders frames whose shift was
    large (the reach window may have clipped them). Returns (height, settled poses, valid):
    a frame is invalid when no shift settles it, i.e. another part of the object sits behind
    the gel plane (the sensor body would collide with it, as in a scissors' handle ring).

    ``peak_step``: first probe every ``peak_step``-th pixel (``MeshDepthRenderer.peak_height``)
    and move the frames the probe finds far off (those the second pass would re-render)
    before the full render. On curved objects most frames start millimetres off, and the
    probe costs 1/16 of the re-render it saves; frames found close are not touched (their
    result is the one without the probe, to ~1e-8 mm of float rounding). The probe acts as
    one more correction, so a few frames two passes would leave unsettled (dropped as
    collisions) settle. None: no probe.
    """
    with timed_span("settle"):
        return _settle_press(renderer, poses, press_mm, passes, peak_step)


def _settle_press(
    renderer: MeshDepthRenderer,
    poses: np.ndarray,
    press_mm: np.ndarray,
    passes: int,
    peak_step: int | None = None,
) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    poses = poses.copy()
    if peak_step and passes > 0:
        guess = press_mm - renderer.peak_height(poses, peak_step)
        far = np.abs(guess) > 0.25 * renderer.reach_mm  # what the redo test below uses
        poses[far, :3, 3] += poses[far, :3, 2] * guess[far, None]
    height = renderer.render_height(poses)
    for _ in range(passes):
        shift = press_mm - height.flatten(1).amax(1).numpy()
        poses[:, :3, 3] += poses[:, :3, 2] * shift[:, None]
        height += torch.from_numpy(shift.astype(np.float32))[:, None, None, None]
        redo = np.abs(shift) > 0.25 * renderer.reach_mm
        if not redo.any():
            break
        height[torch.from_numpy(redo)] = renderer.render_height(poses[redo])
    valid = np.abs(height.flatten(1).amax(1).numpy() - press_mm) < 0.01
    return height, poses, valid


#: frames rendered at a time along a trajectory; each chunk draws from its own generator
TRAJECTORY_CHUNK = 64


def chunk_generator(object_seed: int, trajectory: int, chunk: int) -> torch.Generator:
    """The generator of one chunk of a trajectory (sim noise, surrogate randomness).

    Seeded by (object, trajectory, chunk) alone, so any chunk can be rendered in any process
    and order with the same result: the builder can split one object's frames evenly over
    the workers.
    """
    seed = np.random.SeedSequence([object_seed, trajectory, chunk]).generate_state(1)[0]
    return torch.Generator().manual_seed(int(seed))


def trajectory_chunks(frames: int) -> int:
    """Number of ``TRAJECTORY_CHUNK``-frame chunks of a trajectory of ``frames`` frames."""
    return -(-frames // TRAJECTORY_CHUNK)


def trajectory_pairs(
    renderer: MeshDepthRenderer,
    traj: Trajectory,
    gel: GelSpec,
    sim_optics: SimOptics,
    sim_background: torch.Tensor,
    real_sensor: SurfaceSensor,
    object_seed: int,
    chunks: range,
) -> dict[str, Any]:
    """The valid pairs of chunks ``chunks`` of ``traj`` (possibly none), with their meta."""
    depth, sim, real, poses, keep = [], [], [], [], []
    for c in chunks:
        sl = slice(c * TRAJECTORY_CHUNK, (c + 1) * TRAJECTORY_CHUNK)
        press = traj.press_mm[sl].astype(np.float64)
        true_h, true_p, ok_true = settle_press(renderer, traj.poses[sl], press)
        meas_h, _, ok_meas = settle_press(renderer, traj.measured[sl], press)
        ok = ok_true & ok_meas
        if not ok.any():
            continue
        generator = chunk_generator(object_seed, traj.index, c)
        mask = torch.from_numpy(ok)
        with timed_span("sim.depth"):
            d = to_depth(meas_h[mask], gel, inplace=True)  # [mask] is a copy of our own
        depth.append(d)
        with timed_span("sim.optics"):
            s = sim_optics.render(d, sim_background, generator, gel)
        with timed_span("uint8"):
            sim.append(to_uint8(s))
        r = real_sensor.render_surface(true_h[mask], gel, generator)
        with timed_span("uint8"):
            real.append(to_uint8(r))
        poses.append(true_p[ok])
        keep.append(np.arange(sl.start, sl.start + len(press))[ok])
    frame = np.concatenate(keep) if keep else np.zeros(0, dtype=np.int64)
    s = gel.size
    return {
        "depth": torch.cat(depth) if depth else torch.zeros(0, 1, s, s),
        "sim": torch.cat(sim) if sim else torch.zeros(0, 3, s, s, dtype=torch.uint8),
        "real": torch.cat(real) if real else torch.zeros(0, 3, s, s, dtype=torch.uint8),
        "poses": np.concatenate(poses) if poses else np.zeros((0, 4, 4)),
        "frame": frame,
        "press_mm": traj.press_mm[frame],
        "velocity_mm_s": traj.velocity_mm_s[frame],
        "time_s": traj.time_s[frame].astype(np.float32),
    }
