"""pix2pix conditional GAN translator (the paper's cGAN baseline)."""

from tactile_bench.translators.cgan.lightning_model import CGANConfig, CGANTranslator
from tactile_bench.translators.cgan.torch_model import PatchDiscriminator, UNetGenerator

__all__ = ["CGANConfig", "CGANTranslator", "PatchDiscriminator", "UNetGenerator"]
