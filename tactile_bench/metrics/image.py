"""Paired image similarity in the paper's units: SSIM and MSE on 0..255 pixel values.

The paper reports diffusion SSIM 0.908 / MSE 36.02 and cGAN 0.879 / 47.99 on its braille
test set; to compare against those numbers, both are computed on 0..255 RGB images
(uint8 or float), SSIM with data_range 255 and the standard 11 x 11 Gaussian window.
"""

from __future__ import annotations

import torch
from torchmetrics.functional.image import structural_similarity_index_measure


def _as_float255(images: torch.Tensor) -> torch.Tensor:
    if images.dim() == 3:
        images = images.unsqueeze(0)
    return images.to(torch.float32)


#: images per SSIM call: torchmetrics stacks five padded float copies of its batch, so a
#: whole test set at once takes gigabytes; 64 at a time stays small (docs/results/code_figures.md)
SSIM_CHUNK = 64


def ssim_mse(pred: torch.Tensor, target: torch.Tensor) -> dict[str, float]:
    """Mean SSIM and mean squared error over a batch of (N, 3, S, S) images in 0..255.

    SSIM is the mean of per-image SSIMs, computed a chunk at a time to bound memory.
    """
    pred, target = _as_float255(pred), _as_float255(target)
    if pred.shape != target.shape:
        raise ValueError(f"shape mismatch: {tuple(pred.shape)} vs {tuple(target.shape)}")
    per_image = [
        structural_similarity_index_measure(
            pred[i : i + SSIM_CHUNK],
            target[i : i + SSIM_CHUNK],
            data_range=255.0,
            reduction="none",
        )
        for i in range(0, len(pred), SSIM_CHUNK)
    ]
    ssim = torch.cat(per_image).mean()
    mse = torch.mean((pred - target) ** 2)
    return {"ssim": float(ssim), "mse": float(mse)}
