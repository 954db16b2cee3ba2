"""The cGAN generator's norm decides how far an output pixel sees: instance norm makes every
pixel depend on the whole image, batch norm at inference only on its receptive field."""

from __future__ import annotations

from typing import ClassVar

import pytest
import torch

from tactile_bench.translators.cgan.lightning_model import CGANConfig, CGANTranslator
from tactile_bench.translators.cgan.torch_model import Norm, UNetGenerator, Upsample, upsampling


def _far_corner_change(norm: str) -> float:
    """Largest output change in one corner when a press appears in the opposite corner, 120
    px away (further than three halvings' convolutions reach)."""
    torch.manual_seed(0)
    generator = UNetGenerator(1, 3, base_channels=4, num_downs=3, norm=norm).eval()
    if norm == "batch":  # running statistics as after training, not the fresh 0 / 1
        for module in generator.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.1, 0.1)
                module.running_var.uniform_(0.5, 1.5)
    depth = torch.rand(1, 1, 128, 128) * 0.1
    pressed = depth.clone()
    pressed[..., :8, :8] += 1.0
    with torch.no_grad():
        before, after = generator(depth), generator(pressed)
    return float((after - before)[..., -8:, -8:].abs().max())


def test_instance_norm_reaches_across_the_image() -> None:
    assert _far_corner_change("instance") > 1e-4


def test_batch_norm_at_inference_sees_only_its_receptive_field() -> None:
    assert _far_corner_change("batch") == 0.0


class _BatchNormCGAN(CGANTranslator):
    """A variant as scripts/cgan_ab registers them: a subclass that names another norm."""

    name = "test_cgan_bn"
    generator_norm: ClassVar[Norm] = "batch"


class _ResizeCGAN(CGANTranslator):
    name = "test_cgan_resize"
    generator_upsample: ClassVar[Upsample] = "resize"


@pytest.mark.parametrize(("kind", "batch"), [(CGANTranslator, False), (_BatchNormCGAN, True)])
def test_the_translator_builds_its_class_norm(kind: type[CGANTranslator], batch: bool) -> None:
    translator = kind(CGANConfig(generator_channels=4))
    kinds = {type(m).__name__ for m in translator.generator.modules()}
    assert ("BatchNorm2d" in kinds) is batch
    assert ("InstanceNorm2d" in kinds) is not batch


def test_generator_options_are_not_config_keys() -> None:
    """The variants are classes, not settings: the table's cgan config refuses them."""
    with pytest.raises(ValueError, match="generator_norm"):
        CGANConfig(generator_norm="batch")


@pytest.mark.parametrize(("kind", "alternates"), [("transpose", True), ("resize", False)])
def test_transposed_convolutions_alternate_kernels_pixel_by_pixel(
    kind: str, alternates: bool
) -> None:
    """A flat input comes out of a stride-2 transposed convolution with a pixel-period pattern
    (four kernels take turns); resize + convolution keeps it flat away from the border."""
    torch.manual_seed(0)
    layer = upsampling(4, 1, kind, bias=False)
    with torch.no_grad():
        out = layer(torch.ones(1, 4, 8, 8))[0, 0, 2:-2, 2:-2]
    step = float((out[:, 1:] - out[:, :-1]).abs().max())
    assert (step > 1e-3) is alternates


def test_the_translator_builds_its_class_upsampling() -> None:
    translator = _ResizeCGAN(CGANConfig(generator_channels=4))
    kinds = {type(m).__name__ for m in translator.generator.modules()}
    assert "ConvTranspose2d" not in kinds and "Upsample" in kinds
    assert translator.generator(torch.zeros(1, 1, 64, 64)).shape == (1, 3, 64, 64)
