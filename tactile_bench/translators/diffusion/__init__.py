"""Conditional diffusion translator (the paper's method): network, samplers, Lightning module."""

from tactile_bench.translators.diffusion.lightning_model import (
    DiffusionConfig,
    DiffusionTranslator,
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
    "make_sampler",
    "sample",
]
