"""The ``cgan`` translator: the paper's pix2pix baseline, trained with manual optimisation.

The generator sees depth_mm / ``depth_scale_mm`` and outputs tanh values t in [-1, 1];
foreground = 0.5 + t / 2, i.e. pix2pix's usual [-1, 1] image space applied to the
background-free foreground, so every foreground in 0..1 is reachable.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, ClassVar

import torch
from lightning.pytorch.loggers import Logger
from pydantic import Field

from tactile_bench.training import FitReport
from tactile_bench.translators.base import Translator, TranslatorConfig
from tactile_bench.translators.cgan.divergence import DivergenceMonitor
from tactile_bench.translators.cgan.loss import discriminator_loss, generator_loss
from tactile_bench.translators.cgan.torch_model import (
    Norm,
    PatchDiscriminator,
    UNetGenerator,
    Upsample,
)

log = logging.getLogger("tactile_bench")


class CGANConfig(TranslatorConfig):
    """pix2pix defaults (Adam 2e-4, betas (0.5, 0.999), lambda_L1 = 100), CPU-sized networks.

    ``max_steps`` counts generator updates (each also makes one discriminator update).
    ``divergence_window`` / ``divergence_factor``: see :class:`DivergenceMonitor`.
    """

    max_steps: int = Field(default=1000, ge=0, description="generator updates")
    lr: float = Field(default=2e-4, gt=0, description="Adam learning rate of both networks")
    beta1: float = Field(default=0.5, ge=0, lt=1, description="Adam beta1 (pix2pix: 0.5)")
    l1_weight: float = Field(
        default=100.0, ge=0, description="weight of the L1 term against the adversarial one"
    )
    generator_channels: int = Field(
        default=16, ge=1, description="channels of the U-Net generator's first layer"
    )
    num_downs: int = Field(
        default=4, ge=2, description="halvings of the U-Net (the image side must divide by 2**n)"
    )
    discriminator_channels: int = Field(
        default=16, ge=1, description="channels of the PatchGAN discriminator's first layer"
    )
    discriminator_layers: int = Field(
        default=3, ge=1, description="strided layers of the PatchGAN discriminator"
    )
    dropout: float = Field(
        default=0.5, ge=0, lt=1, description="dropout of the innermost decoder layers"
    )
    depth_scale_mm: float = Field(
        default=1.0, gt=0, description="the generator sees depth in mm divided by this"
    )
    divergence_window: int = Field(
        default=50, ge=2, description="steps of the loss averages the divergence check watches"
    )
    divergence_factor: float = Field(
        default=3.0, gt=1, description="L1 average this many times its best so far: divergence"
    )


class CGANTranslator(Translator):
    """Depth -> foreground with a U-Net generator; deterministic at inference (no dropout)."""

    name = "cgan"
    Config = CGANConfig
    #: the generator's norm and upsampling: pix2pix's, which the table's row uses. A variant
    #: is a subclass registered under its own name (scripts/cgan_ab/ holds the A/B's)
    generator_norm: ClassVar[Norm] = "instance"
    generator_upsample: ClassVar[Upsample] = "transpose"

    def __init__(self, config: CGANConfig | dict[str, Any] | None = None) -> None:
        super().__init__(config)
        self.automatic_optimization = False
        cfg = self.config
        with torch.random.fork_rng(devices=[]):  # same seed -> same initial weights
            torch.manual_seed(cfg.seed)
            self.generator = UNetGenerator(
                1,
                3,
                cfg.generator_channels,
                cfg.num_downs,
                dropout=cfg.dropout,
                norm=self.generator_norm,
                upsample=self.generator_upsample,
            )
            self.discriminator = PatchDiscriminator(
                4, cfg.discriminator_channels, cfg.discriminator_layers
            )
        self.monitor = DivergenceMonitor(cfg.divergence_window, cfg.divergence_factor)

    def condition(self, depth: torch.Tensor) -> torch.Tensor:
        return depth.float() / self.config.depth_scale_mm

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        """Generator output in [-1, 1] (pix2pix image space)."""
        return self.generator(self.condition(depth))

    def fit_pairs(
        self,
        depth: torch.Tensor,
        foreground: torch.Tensor,
        out_dir: Path,
        trainer: dict[str, Any] | None = None,
        loggers: list[Logger] | None = None,
    ) -> FitReport | None:
        """As the base class, but Lightning counts both optimisers' steps: ask for twice as many."""
        settings = {"max_steps": 2 * self.config.max_steps, **(trainer or {})}
        return super().fit_pairs(depth, foreground, out_dir, settings, loggers)

    def fit_diagnostics(self) -> dict[str, Any]:
        """``divergence``: None, or where and why the fit started to diverge."""
        return {"divergence": self.monitor.event}

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["divergence_monitor"] = self.monitor.state_dict()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        if "divergence_monitor" in checkpoint:
            self.monitor.load_state_dict(checkpoint["divergence_monitor"])

    def training_step(
        self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int
    ) -> dict[str, torch.Tensor]:
        depth, foreground = batch
        g_opt, d_opt = self.optimizers()
        condition = self.condition(depth)
        real = (foreground.float() - 0.5) * 2.0
        fake = self.generator(condition)

        d_loss = discriminator_loss(
            self.discriminator(condition, real), self.discriminator(condition, fake.detach())
        )
        d_opt.zero_grad()
        self.manual_backward(d_loss)
        d_opt.step()

        g_loss, adversarial, l1 = generator_loss(
            self.discriminator(condition, fake), fake, real, self.config.l1_weight
        )
        g_opt.zero_grad()
        self.manual_backward(g_loss)
        g_opt.step()
        losses = {"d_loss": d_loss, "g_loss": g_loss, "g_adv": adversarial, "g_l1": l1}
        self.log_dict(losses, prog_bar=True, batch_size=len(depth))
        values = {k: float(v.detach()) for k, v in losses.items()}
        if all(math.isfinite(v) for v in values.values()):  # NaN/inf: the fit's guard stops it
            news = self.monitor.update(values["d_loss"], values["g_adv"], values["g_l1"])
            if news is not None:
                log.warning("cgan fit diverging at step %d: %s", news["step"], news["why"])
        return {k: v.detach() for k, v in losses.items()}

    def configure_optimizers(self) -> list[torch.optim.Optimizer]:
        betas = (self.config.beta1, 0.999)
        return [
            torch.optim.Adam(self.generator.parameters(), lr=self.config.lr, betas=betas),
            torch.optim.Adam(self.discriminator.parameters(), lr=self.config.lr, betas=betas),
        ]

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Deterministic: ``generator`` is unused (pix2pix's dropout noise is off at inference)."""
        return (0.5 + 0.5 * self(depth)).clamp(0.0, 1.0)
