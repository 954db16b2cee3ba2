"""The ``lighting_aug`` translator: the paper's "Sim + data aug." baseline.

Sim images (the ``sim`` translator's TACTO-like rendering) randomised by lighting and camera
augmentations, so a classifier trained on them sees many plausible illuminations instead of
one ideal one. All augmentations are one kornia ``AugmentationSequential`` on images in [0, 1].
Nothing is learned. kornia draws from torch's global RNG, so each call runs inside a forked
RNG seeded from the caller's generator: same generator seed, same images, global state intact.
"""

from __future__ import annotations

from typing import Any

import kornia.augmentation as K
import torch
from pydantic import Field

from tactile_bench.sensor.background import sim_background
from tactile_bench.translators.base import image_to_foreground
from tactile_bench.translators.sim import SimConfig, SimTranslator

Range = tuple[float, float]


class LightingAugConfig(SimConfig):
    """Augmentation strengths (ranges, probabilities); moderate, photometric-only defaults."""

    brightness: float = Field(default=0.2, ge=0, le=1, description="ColorJitter brightness")
    contrast: float = Field(default=0.2, ge=0, description="ColorJitter contrast")
    saturation: float = Field(default=0.2, ge=0, description="ColorJitter saturation")
    hue: float = Field(default=0.03, ge=0, le=0.5, description="ColorJitter hue")
    gamma: Range = Field(default=(0.8, 1.25), description="range of the random gamma")
    planckian_p: float = Field(
        default=0.5, ge=0, le=1, description="probability of a black-body colour temperature"
    )
    linear_illumination_gain: Range = Field(
        default=(0.01, 0.15), description="gain range of the linear and corner light gradients"
    )
    illumination_p: float = Field(
        default=0.5, ge=0, le=1, description="probability of each light gradient"
    )
    noise_std: float = Field(default=0.02, ge=0, description="std of the Gaussian pixel noise")
    noise_p: float = Field(default=0.5, ge=0, le=1, description="probability of that noise")
    blur_sigma: Range = Field(default=(0.1, 1.0), description="sigma range of the Gaussian blur")
    blur_p: float = Field(default=0.3, ge=0, le=1, description="probability of that blur")


def build_augmentation(cfg: LightingAugConfig) -> K.AugmentationSequential:
    """One kornia pipeline: global photometry, colour temperature, uneven light, camera."""
    return K.AugmentationSequential(
        K.ColorJitter(cfg.brightness, cfg.contrast, cfg.saturation, cfg.hue, p=1.0),
        K.RandomGamma(gamma=cfg.gamma, p=1.0),
        K.RandomPlanckianJitter(mode="blackbody", p=cfg.planckian_p),
        K.RandomLinearIllumination(gain=cfg.linear_illumination_gain, p=cfg.illumination_p),
        K.RandomLinearCornerIllumination(gain=cfg.linear_illumination_gain, p=cfg.illumination_p),
        K.RandomGaussianBlur((5, 5), cfg.blur_sigma, p=cfg.blur_p),
        K.RandomGaussianNoise(std=cfg.noise_std, p=cfg.noise_p),
        data_keys=["input"],
    )


class LightingAugTranslator(SimTranslator):
    """Depth -> sim image with randomised lighting. Not trainable."""

    name = "lighting_aug"
    Config = LightingAugConfig
    trainable = False

    def __init__(self, config: LightingAugConfig | dict[str, Any] | None = None) -> None:
        super().__init__(config)
        self.augment = build_augmentation(self.config)

    def augmented(
        self, depth: torch.Tensor, background: torch.Tensor, generator: torch.Generator | None
    ) -> torch.Tensor:
        """Sim image on ``background`` (0..255), then lighting randomisation; 0..255 out."""
        generator = self._generator(generator)
        image = self.optics.render(depth.float(), background.float(), generator)
        seed = int(torch.randint(0, 2**62, (1,), generator=generator))
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            out = self.augment(image / 255.0)
        return (out.clamp(0.0, 1.0) * 255.0).to(image.dtype)

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        background = sim_background(depth.shape[-1])
        return image_to_foreground(self.augmented(depth, background, generator), background)

    @torch.no_grad()
    def translate(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        return self.augmented(depth, background, generator)
