"""Pixel noise of a set of frames, measured frame to frame as a camera's noise is.

Shared by the diffusion translator (it samples the noise it measured on its training frames)
and the gap diagnosis (it raises training sets cleaner than the real frames to their noise):
both only measure images, so the estimator lives with the other image measures.
"""

from __future__ import annotations

import math

import torch

MIN_FRAMES = 8  # fewer frames give no usable per-pixel median


def clipped_std(deviation: torch.Tensor) -> torch.Tensor:
    """Per-row std (C,) of zero-mean deviations (C, M), 3-sigma clipped (two rounds,
    truncation corrected): sparse values that are not noise (contact pixels) do not count."""
    sigma = math.sqrt(math.pi / 2) * deviation.abs().mean(dim=1)  # first guess, inflated
    for _ in range(2):
        inside = deviation.abs() <= 3.0 * sigma[:, None]
        kept = inside.sum(dim=1).clamp(min=1)
        sigma = ((deviation**2 * inside).sum(dim=1) / kept).sqrt() / 0.9866  # +-3 sigma cut
    return sigma


def estimate_pixel_noise(
    foreground: torch.Tensor, free: torch.Tensor | None = None
) -> torch.Tensor | None:
    """Per-channel std (C,) of the pixel noise in a batch of frames (N, C, H, W).

    Frame to frame, as a camera's noise is measured: each pixel's deviation from its median
    over the batch is noise wherever no contact touches it, which is most of the gel. The
    std of the deviations is taken with 3-sigma clipping (``clipped_std``), so contact
    pixels do not count; ``free`` (N, 1, H, W), True away from every contact, leaves them
    out altogether (the clipping alone read the surrogate's real braille frames 2.0 grey
    levels against 1.4 with the contacts masked). Unlike a spatial (Laplacian) estimate this
    also captures noise that is correlated between neighbouring pixels (demosaicing,
    compression): a spatial estimate gave real braille frames half the std. Returns None
    for fewer than ``MIN_FRAMES`` frames.
    """
    if len(foreground) < MIN_FRAMES:
        return None
    x = foreground.float()
    deviation = (x - x.median(dim=0).values).transpose(0, 1)
    if free is None:
        return clipped_std(deviation.reshape(x.shape[1], -1))
    mask = free.expand_as(x).transpose(0, 1)
    if int(mask[0].sum()) < MIN_FRAMES:
        return None
    return clipped_std(deviation[mask].reshape(x.shape[1], -1))
