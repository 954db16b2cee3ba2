"""The ``sim`` translator: the simple simulator's own rendering, nothing learned.

It is the identity baseline of the paper's table (the "Sim" rows): TACTO-like
Phong shading of the depth with three ideal point lights plus Gaussian noise,
composited onto whichever background the caller gives.
"""

from __future__ import annotations

import torch
from pydantic import Field

from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.translators.base import Translator, TranslatorConfig, image_to_foreground


class SimConfig(TranslatorConfig):
    """Nothing to fit: only the seed of the sensor noise (``max_steps`` is ignored)."""

    max_steps: int = Field(default=0, description="ignored: the simulator has nothing to fit")


class SimTranslator(Translator):
    """Depth -> TACTO-like image. Not trainable."""

    name = "sim"
    Config = SimConfig
    trainable = False

    def __init__(self, config: SimConfig | dict | None = None) -> None:
        super().__init__(config)
        self.optics = SimOptics()

    def _generator(self, generator: torch.Generator | None) -> torch.Generator:
        return (
            generator if generator is not None else torch.Generator().manual_seed(self.config.seed)
        )

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        background = sim_background(depth.shape[-1]).to(depth.device)
        image = self.optics.render(depth, background, self._generator(generator))
        return image_to_foreground(image, background)

    @torch.no_grad()
    def translate(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        background = background.float().to(depth.device)
        return self.optics.render(depth.float(), background, self._generator(generator))
