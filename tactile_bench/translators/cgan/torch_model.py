"""pix2pix networks (Isola et al. 2017): a U-Net generator and a PatchGAN discriminator.

Deviations from the original, for a deterministic CPU baseline: instance norm instead of
batch norm (pix2pix trains with batch 1, where the two coincide, and instance norm has no
running statistics to drift between train and eval), and dropout only while training, so
``translate`` is a deterministic function of the depth.

The generator's norm is a choice (``norm``): instance norm divides every feature map by its
own image's statistics, so each output pixel depends on the whole image, however far its
convolutions reach; batch norm evaluated with its running statistics does not. So is its
upsampling (``upsample``): pix2pix's stride-2 transposed convolutions, whose output pixels
alternate between four kernels, or a nearest-neighbour resize followed by a convolution,
which Odena, Dumoulin & Olah (2016, "Deconvolution and checkerboard artifacts", Distill)
propose against the pixel-period pattern the former draws.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import nn

Norm = Literal["instance", "batch"]
Upsample = Literal["transpose", "resize"]


def _norm(channels: int, kind: Norm = "instance") -> nn.Module:
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    return nn.InstanceNorm2d(channels, affine=True)


def upsampling(in_channels: int, out_channels: int, kind: Upsample, bias: bool) -> nn.Module:
    """Doubles the side: a 4 x 4 stride-2 transposed convolution, or resize + 3 x 3 conv."""
    if kind == "resize":
        return nn.Sequential(
            nn.Upsample(scale_factor=2, mode="nearest"),
            nn.Conv2d(in_channels, out_channels, 3, 1, 1, bias=bias),
        )
    return nn.ConvTranspose2d(in_channels, out_channels, 4, 2, 1, bias=bias)


class UNetGenerator(nn.Module):
    """Encoder-decoder with skips; ``num_downs`` halvings, so S must divide by 2**num_downs."""

    def __init__(
        self,
        in_channels: int = 1,
        out_channels: int = 3,
        base_channels: int = 16,
        num_downs: int = 4,
        max_channels: int = 128,
        dropout: float = 0.5,
        norm: Norm = "instance",
        upsample: Upsample = "transpose",
    ) -> None:
        super().__init__()
        widths = [min(base_channels * 2**i, max_channels) for i in range(num_downs)]
        self.down = nn.ModuleList()
        previous = in_channels
        for i, width in enumerate(widths):
            layers: list[nn.Module] = [nn.Conv2d(previous, width, 4, 2, 1, bias=False)]
            if 0 < i < num_downs - 1:  # no norm on the first layer nor on the 1x1-ish bottleneck
                layers.append(_norm(width, norm))
            layers.append(nn.LeakyReLU(0.2))
            self.down.append(nn.Sequential(*layers))
            previous = width
        self.up = nn.ModuleList()
        for i in reversed(range(num_downs - 1)):
            # input: previous decoder output, concatenated with the skip after the first level
            in_ch = previous if i == num_downs - 2 else previous * 2
            layers = [
                upsampling(in_ch, widths[i], upsample, bias=False),
                _norm(widths[i], norm),
            ]
            if dropout > 0 and i >= num_downs - 3:  # dropout on the innermost decoders only
                layers.append(nn.Dropout(dropout))
            layers.append(nn.ReLU())
            self.up.append(nn.Sequential(*layers))
            previous = widths[i]
        self.out = nn.Sequential(
            upsampling(previous * 2, out_channels, upsample, bias=True), nn.Tanh()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for layer in self.down:
            x = layer(x)
            skips.append(x)
        skips.pop()  # the bottleneck is x itself
        for layer in self.up:
            x = torch.cat([layer(x), skips.pop()], dim=1)
        return self.out(x)


class PatchDiscriminator(nn.Module):
    """Scores overlapping patches of a (condition, image) pair as real or generated (logits)."""

    def __init__(self, in_channels: int = 4, base_channels: int = 16, n_layers: int = 3) -> None:
        super().__init__()
        layers: list[nn.Module] = [
            nn.Conv2d(in_channels, base_channels, 4, 2, 1),
            nn.LeakyReLU(0.2),
        ]
        width = base_channels
        for i in range(1, n_layers + 1):
            previous, width = width, base_channels * min(2**i, 8)
            stride = 2 if i < n_layers else 1
            layers += [
                nn.Conv2d(previous, width, 4, stride, 1, bias=False),
                _norm(width),
                nn.LeakyReLU(0.2),
            ]
        layers.append(nn.Conv2d(width, 1, 4, 1, 1))
        self.model = nn.Sequential(*layers)

    def forward(self, condition: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        return self.model(torch.cat([condition, image], dim=1))
