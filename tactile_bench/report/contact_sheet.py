"""Contact sheets: what each effect of the surrogate DIGIT does, one column per effect.

Columns: depth | sim | the surrogate with only one effect on (one column each) | the
surrogate with every effect of its profile on. Rows: braille characters (a centred
contact) and pretraining objects (the frame of a sliding trajectory with the largest
contact patch). Every column shares
the seed, so a column differs from ``sim`` only by its effect's physics (and its noise).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from tactile_bench.data.ycb_slide import settle_press
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.geometry.contacts import Poses
from tactile_bench.geometry.objects import object_mesh, object_parts
from tactile_bench.geometry.trajectories import exposed_surface, sliding_trajectories
from tactile_bench.report.figures import sample_grid_png
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit

BRAILLE_PRESS_MM = 0.7


def braille_heights(chars: Sequence[str], gel: GelSpec) -> torch.Tensor:
    """Signed height of a centred, upright contact on each character."""
    bank = build_bank(tuple(chars), BrailleSpec())
    n = len(chars)
    poses = Poses(
        labels=torch.arange(n),
        x_mm=torch.zeros(n),
        y_mm=torch.zeros(n),
        yaw_deg=torch.zeros(n),
        press_mm=torch.full((n,), BRAILLE_PRESS_MM),
    )
    return render_height(bank, poses, gel)


def object_height(name: str, gel: GelSpec, seed: int = 0) -> torch.Tensor:
    """Signed height of the frame of a sliding trajectory with the largest contact patch."""
    parts = object_parts(name, seed)
    (trajectory,) = sliding_trajectories(
        exposed_surface(parts), name, n_trajectories=1, n_frames=60, seed=seed
    )
    renderer = MeshDepthRenderer.from_trimesh(object_mesh(name, seed), gel)
    try:
        height, _, valid = settle_press(renderer, trajectory.poses, np.asarray(trajectory.press_mm))
    finally:
        renderer.close()
    area = (height > 0).float().mean(dim=(1, 2, 3)) * torch.from_numpy(valid).float()
    best = int(area.argmax())
    return height[best : best + 1]


def contact_sheet(
    heights: torch.Tensor,
    row_labels: Sequence[str],
    surrogate: SurrogateDigit,
    gel: GelSpec,
    path: str | Path,
    seed: int = 0,
) -> Path:
    """Write the sheet for rows of signed height (R, 1, H, W) and return its path."""
    depth = to_depth(heights, gel)
    background = sim_background(gel.size)

    def gen() -> torch.Generator:
        return torch.Generator().manual_seed(seed)

    columns: dict[str, torch.Tensor] = {
        "depth": depth,
        "sim": SimOptics().render(depth, background, gen()),
    }
    for name in surrogate.effects_enabled:
        columns[name] = surrogate.only(name).render_surface(heights, gel, gen())
    columns[f"all ({surrogate.name})"] = surrogate.render_surface(heights, gel, gen())
    return sample_grid_png(
        columns,
        list(row_labels),
        path,
        title=f"surrogate DIGIT '{surrogate.name}': each effect alone, then all "
        "(pose effects act on contact poses and show no change on a fixed height map)",
    )


def render_contact_sheet(
    chars: Sequence[str], objects: Sequence[str], profile: str, out: str | Path, seed: int = 0
) -> Path:
    """Build the rows for characters and objects and write the sheet."""
    gel = GelSpec()
    rows, labels = [], []
    if chars:
        rows.append(braille_heights(chars, gel))
        labels += [f"braille {c}" for c in chars]
    for name in objects:
        rows.append(object_height(name, gel, seed))
        labels.append(name)
    heights = torch.cat(rows)
    return contact_sheet(heights, labels, SurrogateDigit.from_profile(profile), gel, out, seed)
