"""Conditional diffusion translator (the paper's method): network, samplers, Lightning module."""

from tactile_bench.translators.diffusion.lightning_model import (
    DiffusionConfig,
    DiffusionTranslator,
    estimate_pixel_noise,
)
from tactile_bench.translators.diffusion.sampling import SAMPLERS, make_sampler, sample
from tactile_bench.translators.diffusion.torch_model import PRESETS, UNetSpec, build_unet

__all__ = [
    "PRESETS",
    "SAMPLERS",
    "DiffusionConfig",
    "DiffusionTranslator",
    "UNetSpec",
    "build_unet",
    "estimate_pixel_noise",
    "make_sampler",
    "sample",
]
