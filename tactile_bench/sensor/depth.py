"""Contact depth images: a braille contact is a rigid transform of the block's height field.

TACTO renders the object mesh with an OpenGL depth camera behind the gel and takes the gel
penetration as the object surface minus the undeformed gel plane where it is positive: rigid
penetration, the gel does not deform around the object. For a block pressed flat onto the gel
that image is exactly the block's height field, translated, rotated and offset by the press,
so we sample the precomputed ``HeightFieldBank`` with ``grid_sample`` instead of rendering:
the same numbers (up to the field's ~0.1 mm sampling) at thousands of contacts a second.

Sensor frame: x along the gel width (image columns, left to right), y along the gel height
(image rows run from +y at the top to -y at the bottom), origin at the gel centre, so the image
reads like the block seen from above through the gel.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from tactile_bench.effects.kernels import area_pool
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor.heightfield import HeightFieldBank


@dataclass(frozen=True)
class GelSpec:
    """The gel as the camera sees it: a width_mm x height_mm view resized to size x size.

    ``oversample`` renders heights at size * oversample and area-averages down, so a dot
    edge is anti-aliased like a camera pixel integrates light.
    """

    width_mm: float = 18.0
    height_mm: float = 24.0
    size: int = 64
    oversample: int = 2

    def __post_init__(self) -> None:
        if self.width_mm <= 0 or self.height_mm <= 0 or self.size < 2 or self.oversample < 1:
            raise TactileBenchError(f"GelSpec: invalid {self}")

    @property
    def mm_per_px(self) -> tuple[float, float]:
        """(x, y) size of one model pixel in mm (pixels are not square: 18 x 24 mm -> S x S)."""
        return self.width_mm / self.size, self.height_mm / self.size


def _thetas(bank: HeightFieldBank, poses: Poses, gel: GelSpec) -> torch.Tensor:
    """(N, 2, 3) affine maps from normalised sensor-image coords to normalised bank coords.

    A sensor point (x, y) = (ox * W/2, -oy * H/2) sees the object point
    R(-yaw) (x, y) - (x_mm, y_mm); the bank's normalised coords are (px, -py) / half extent.
    """
    yaw = torch.deg2rad(poses.yaw_deg)
    c, s = torch.cos(yaw), torch.sin(yaw)
    w, h = gel.width_mm / 2, gel.height_mm / 2
    theta = torch.stack(
        [
            torch.stack([c * w, -s * h, -poses.x_mm], -1),
            torch.stack([s * w, c * h, poses.y_mm], -1),
        ],
        1,
    )
    return theta / bank.half_extent_mm


def affine_grid(theta: torch.Tensor, side: int) -> torch.Tensor:
    """``F.affine_grid(theta, [k, 1, side, side], align_corners=False)``, computed faster
    (docs/results/code_figures.md).

    The map is affine, so the grid is a row term plus a column term: broadcast adds instead
    of a batched matmul against the homogeneous base grid (same values to ~1 ulp). One add
    per coordinate, each along a whole row, into the interleaved grid: faster than one add
    over (x, y) pairs, whose innermost run of 2 values defeats vectorisation.
    """
    base = (torch.arange(side, dtype=theta.dtype) * 2 + 1) / side - 1
    t = theta.transpose(1, 2)[:, None, None]  # (k, 1, 1, 3, 2): columns x, y, offset
    along_x = torch.addcmul(t[..., 2, :], base[None, None, :, None], t[..., 0, :])  # (k,1,W,2)
    along_y = base[None, :, None, None] * t[..., 1, :]  # (k, H, 1, 2)
    grid = torch.empty(theta.shape[0], side, side, 2, dtype=theta.dtype)
    for c in range(2):
        torch.add(along_x[..., c], along_y[..., c], out=grid[..., c])
    return grid


def render_height(
    bank: HeightFieldBank, poses: Poses, gel: GelSpec, chunk: int = 256
) -> torch.Tensor:
    """Signed height (N, 1, size*oversample, size*oversample), mm, positive inside the gel.

    The block is translated by (x_mm, y_mm), rotated by yaw_deg (counter-clockwise) about the
    sensor centre and pressed until its highest point is press_mm into the gel:
    ``signed = h(object point) - (max h - press_mm)``. Contacts are grouped by label so that
    each group is one ``affine_grid`` + ``grid_sample`` on its own map (no per-contact copies
    of the field). Contacts that differ only in press (the protocols' grids press every
    placement to four depths) share one sample of the map: the press is only an offset.
    """
    n = len(poses)
    labels = poses.labels
    if n and (int(labels.min()) < 0 or int(labels.max()) >= len(bank)):
        raise TactileBenchError(f"render_height: labels outside the bank's {len(bank)} chars")
    side = gel.size * gel.oversample
    offset = bank.top_max.float()[labels] - poses.press_mm
    placement = torch.stack([labels.float(), poses.x_mm, poses.y_mm, poses.yaw_deg], 1)
    unique, inverse = torch.unique(placement, dim=0, return_inverse=True)
    if len(unique) < n:
        first = torch.full((len(unique),), n, dtype=torch.long).scatter_reduce_(
            0, inverse, torch.arange(n), "amin"
        )  # one contact of each placement
        h = sample_maps(bank, poses.index(first), gel, chunk, side)
        return h[inverse].sub_(offset.view(n, 1, 1, 1))
    return sample_maps(bank, poses, gel, chunk, side).sub_(offset.view(n, 1, 1, 1))


def sample_maps(
    bank: HeightFieldBank, poses: Poses, gel: GelSpec, chunk: int, side: int
) -> torch.Tensor:
    """The bank's map of each contact's label, moved and turned to its placement."""
    labels = poses.labels
    out = torch.empty(len(poses), 1, side, side, dtype=torch.float32)
    maps = bank.maps.float()
    thetas = _thetas(bank, poses, gel)
    for label in torch.unique(labels).tolist():
        for idx in torch.nonzero(labels == label).flatten().split(chunk):
            k = len(idx)
            grid = affine_grid(thetas[idx], side)
            h = F.grid_sample(
                maps[label : label + 1],
                grid.view(1, k * side, side, 2),
                mode="bilinear",
                padding_mode="border",
                align_corners=True,
            ).view(k, 1, side, side)
            out.index_copy_(0, idx, h)
    return out


def to_depth(height: torch.Tensor, gel: GelSpec, inplace: bool = False) -> torch.Tensor:
    """Gel penetration depth (N, 1, size, size) mm: positive part, area-averaged.

    ``inplace`` takes the positive part in ``height`` itself (one copy fewer, for a caller
    that no longer needs the signed height).
    """
    depth = height.clamp_(min=0) if inplace else height.clamp(min=0)
    if gel.oversample > 1:
        depth = area_pool(depth, gel.oversample)
    return depth


def render_depth(
    bank: HeightFieldBank, poses: Poses, gel: GelSpec, chunk: int = 512
) -> torch.Tensor:
    """``to_depth(render_height(...))`` in chunks, so the oversampled heights never pile up."""
    parts = [
        to_depth(render_height(bank, poses.index(slice(k, k + chunk)), gel), gel)
        for k in range(0, len(poses), chunk)
    ]
    if not parts:
        return torch.zeros(0, 1, gel.size, gel.size)
    return torch.cat(parts)
