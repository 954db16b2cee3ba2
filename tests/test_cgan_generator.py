"""The cGAN generator's norm decides how far an output pixel sees: instance norm makes every
pixel depend on the whole image, batch norm at inference only on its receptive field."""

from __future__ import annotations

import pytest
import torch

from tactile_bench.translators.cgan.lightning_model import CGANConfig, CGANTranslator
from tactile_bench.translators.cgan.torch_model import UNetGenerator, upsampling


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


@pytest.mark.parametrize("norm", ["instance", "batch"])
def test_the_translator_builds_the_configured_norm(norm: str) -> None:
    translator = CGANTranslator(CGANConfig(generator_norm=norm, generator_channels=4))
    kinds = {type(m).__name__ for m in translator.generator.modules()}
    assert ("BatchNorm2d" in kinds) is (norm == "batch")
    assert ("InstanceNorm2d" in kinds) is (norm == "instance")


def test_an_unknown_norm_is_a_config_error() -> None:
    with pytest.raises(ValueError, match="generator_norm"):
        CGANConfig(generator_norm="layer")


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


def test_the_translator_builds_the_configured_upsampling() -> None:
    translator = CGANTranslator(CGANConfig(generator_upsample="resize", generator_channels=4))
    kinds = {type(m).__name__ for m in translator.generator.modules()}
    assert "ConvTranspose2d" not in kinds and "Upsample" in kinds
    assert translator.generator(torch.zeros(1, 1, 64, 64)).shape == (1, 3, 64, 64)
