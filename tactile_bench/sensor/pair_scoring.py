"""Score a sensor profile on paired real data: how close its renders come to the real frames.

Given real (depth, frame) pairs and the real no-contact frame, two models render every
pair: the plain simulator (TACTO-like, noise-free) composited on the real no-contact frame,
and the profile as it renders (its own no-contact field, its effects, noise included,
seeded). Each is measured against the real frames as ``ground --profile`` measures the
real GelSight presses (``press_grounding``): MSE and SSIM over the frame, MSE within two
contact radii. Works on tensors; the command layer reads the folders.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.args import MAX_SIZE, MIN_SIZE
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.press_grounding import contact_mask, press_metrics, sim_render, summarise
from tactile_bench.sensor.surrogate import SurrogateDigit

#: the metrics of a row, in the order they are reported
METRICS = ("mse", "ssim", "contact_mse")


def pool(x: torch.Tensor, size: int) -> torch.Tensor:
    """Area-average (N, C, H, W) frames to ``size`` x ``size``, as the camera pixels integrate."""
    return F.adaptive_avg_pool2d(x, (size, size))


@dataclass
class PairRenders:
    """Pairs at ``size`` x ``size``: the real side (depth, frames, no-contact frame, contact
    mask) and the two models' images of every contact."""

    depth: torch.Tensor  # (N, 1, S, S) mm
    real: torch.Tensor  # (N, 3, S, S) 0..255
    background: torch.Tensor  # (3, S, S) 0..255
    mask: torch.Tensor  # (N, 1, S, S) bool: within two contact radii
    sim: torch.Tensor  # (N, 3, S, S): the plain simulator on the real no-contact frame
    profile: torch.Tensor  # (N, 3, S, S): the profile as it renders


def render_pairs(
    profile: SurrogateDigit,
    depth: torch.Tensor,
    real: torch.Tensor,
    background: torch.Tensor,
    gel: GelSpec,
    seed: int = 0,
) -> PairRenders:
    """Both models' images of the pairs at ``gel.size``; the profile renders from ``depth``
    at its own resolution (about twice the size: its geometry effects act there)."""
    size = gel.size
    small = pool(depth, size)
    generator = torch.Generator().manual_seed(seed)
    bg = pool(background[None], size)[0]
    return PairRenders(
        depth=small,
        real=pool(real, size),
        background=bg,
        mask=contact_mask(small),
        sim=sim_render(small, bg, gel),
        profile=profile.render_surface(depth, gel, generator),
    )


def _check_pairs(depth: torch.Tensor, real: torch.Tensor, background: torch.Tensor) -> None:
    if depth.dim() != 4 or depth.shape[1] != 1 or len(depth) == 0:
        raise TactileBenchError(
            f"score_profile: depth must be (N, 1, H, W), N > 0, got {tuple(depth.shape)}"
        )
    if real.dim() != 4 or real.shape[1] != 3 or len(real) != len(depth):
        raise TactileBenchError(
            f"score_profile: real must be (N, 3, h, w) with N = {len(depth)} as depth, "
            f"got {tuple(real.shape)}"
        )
    if tuple(background.shape) != tuple(real.shape[1:]):
        raise TactileBenchError(
            f"score_profile: background must be (3, h, w) like each real frame "
            f"{tuple(real.shape[1:])}, got {tuple(background.shape)}"
        )


def score_profile(
    profile: SurrogateDigit,
    depth: torch.Tensor,
    real: torch.Tensor,
    background: torch.Tensor,
    gel_mm: Sequence[float],
    size: int = 64,
    seed: int = 0,
) -> dict:
    """The plain simulator and ``profile`` against real pairs, at ``size`` x ``size``.

    ``depth`` (N, 1, H, W) mm, about twice ``size``; ``real`` (N, 3, h, w) and
    ``background`` (3, h, w), 0..255; ``gel_mm`` the (width, height) view they show.
    Returns ``{"n_pairs": N, "sim": {mse, ssim, contact_mse}, "profile": {...},
    "per_frame": {"sim": [...], "profile": [...]}}``: the means over the frames, and each
    frame's row.
    """
    _check_pairs(depth, real, background)
    if not MIN_SIZE <= size <= MAX_SIZE:
        raise TactileBenchError(
            f"score_profile: size must be in {MIN_SIZE}..{MAX_SIZE}, got {size}"
        )
    width, height = (float(v) for v in gel_mm)
    renders = render_pairs(
        profile,
        depth.float(),
        real.float(),
        background.float(),
        GelSpec(width, height, size, 2),
        seed,
    )
    per_frame = {
        name: press_metrics(getattr(renders, name), renders.real, renders.mask)
        for name in ("sim", "profile")
    }
    means = {name: summarise(rows) for name, rows in per_frame.items()}
    return {
        "n_pairs": len(depth),
        **{name: {m: s[m]["mean"] for m in METRICS} for name, s in means.items()},
        "per_frame": per_frame,
    }
