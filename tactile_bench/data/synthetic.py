"""Tiny synthetic (depth, foreground) pairs: what tests and the device bench train on when
the content does not matter, only shapes, speed and determinism."""

from __future__ import annotations

import torch


def tiny_pairs(n: int = 8, size: int = 32, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Synthetic (depth mm, foreground) pairs: a dome per sample and a foreground tinted by it."""
    gen = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    centres = torch.rand(n, 2, generator=gen) - 0.5
    r2 = (xs - centres[:, 0, None, None]) ** 2 + (ys - centres[:, 1, None, None]) ** 2
    depth = (0.8 - 4.0 * r2).clamp(min=0).unsqueeze(1)
    tint = torch.tensor([0.3, -0.2, 0.1]).view(1, 3, 1, 1)
    foreground = 0.5 + tint * depth
    return depth, foreground
