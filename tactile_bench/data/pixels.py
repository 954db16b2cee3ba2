"""The pixel conventions every layer shares, written once.

Images are stored as uint8 (0..255, rounded and clamped); models see foregrounds,
``(image - no-contact frame) / 255 + 0.5`` as in the paper's code (docs/architecture.md), so
one model serves every unit's background. Datasets, translators, classifiers and the reader
all convert through these functions.
"""

from __future__ import annotations

import numpy as np
import torch


def to_uint8(image: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Pixel values as stored: rounded, clamped to 0..255, uint8 (uint8 input unchanged).

    Clamping to integer bounds and rounding commute, so this equals round-then-clamp.
    """
    image = torch.as_tensor(image)
    if image.dtype == torch.uint8:
        return image
    return image.float().clamp(0, 255).round_().to(torch.uint8)


def image_to_foreground(image: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Remove the no-contact frame so models see only what the contact changed."""
    return (image - background) / 255.0 + 0.5


def foreground_to_image(foreground: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Add a background back to a foreground: the inverse of the paper's background removal."""
    return ((foreground - 0.5) * 255.0 + background).clamp(0.0, 255.0)
