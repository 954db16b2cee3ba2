"""The cGAN row's generator variants for the A/B of ``scripts/cgan_generator_ab.yaml``.

Each is the ``cgan`` translator with one change to its generator, registered under its own
name so a recipe, its cache and its checkpoints tell the variants apart:

- ``cgan_bn``: batch norm, evaluated with its running statistics, so an output pixel
  depends only on its receptive field (instance norm's per-image statistics reach across
  the whole image);
- ``cgan_resize``: nearest-neighbour resize + 3 x 3 convolution in place of every stride-2
  transposed convolution (Odena, Dumoulin & Olah 2016, "Deconvolution and checkerboard
  artifacts");
- ``cgan_bn_resize``: both.
"""

from __future__ import annotations

from typing import ClassVar

from tactile_bench.translators.cgan.lightning_model import CGANTranslator
from tactile_bench.translators.cgan.torch_model import Norm, Upsample


class BatchNormCGAN(CGANTranslator):
    """``cgan`` with a batch-norm generator."""

    name = "cgan_bn"
    generator_norm: ClassVar[Norm] = "batch"


class ResizeCGAN(CGANTranslator):
    """``cgan`` whose generator upsamples by resize + convolution."""

    name = "cgan_resize"
    generator_upsample: ClassVar[Upsample] = "resize"


class BatchNormResizeCGAN(CGANTranslator):
    """``cgan`` with both changes."""

    name = "cgan_bn_resize"
    generator_norm: ClassVar[Norm] = "batch"
    generator_upsample: ClassVar[Upsample] = "resize"
