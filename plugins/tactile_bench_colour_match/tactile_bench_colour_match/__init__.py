"""An example plugin translator: simulator shading followed by a learned colour transform."""

from __future__ import annotations

import torch
from pydantic import Field
from torch import nn

from tactile_bench.translators import Translator, TranslatorConfig
from tactile_bench.translators.sim import SimTranslator


class ColourMatchConfig(TranslatorConfig):
    """Adam learning rate and the usual fit settings."""

    lr: float = Field(default=0.01, gt=0, description="Adam learning rate of the colour transform")
    max_steps: int = Field(default=100, ge=0, description="training steps of a fit")


class ColourMatchTranslator(Translator):
    """Sim foreground -> 3 x 3 colour matrix + offset -> real-looking foreground."""

    name = "colour_match"
    Config = ColourMatchConfig

    def __init__(self, config: ColourMatchConfig | dict | None = None) -> None:
        super().__init__(config)
        self.sim = SimTranslator({"seed": self.config.seed})
        self.mix = nn.Conv2d(3, 3, kernel_size=1)
        with torch.no_grad():
            self.mix.weight.copy_(torch.eye(3).view(3, 3, 1, 1))
            self.mix.bias.zero_()

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        sim = self.sim.translate_foreground(depth, generator).to(self.mix.weight)
        return self.mix(sim - 0.5) + 0.5

    def training_step(
        self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int
    ) -> torch.Tensor:
        depth, real = batch
        generator = torch.Generator().manual_seed(self.config.seed + batch_idx)
        loss = nn.functional.mse_loss(self.translate_foreground(depth, generator), real)
        self.log("train/loss", loss, prog_bar=True)
        return loss

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.mix.parameters(), lr=self.config.lr)
