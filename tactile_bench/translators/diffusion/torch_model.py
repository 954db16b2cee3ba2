"""The denoising network: a diffusers ``UNet2DModel`` conditioned by channel concatenation.

As in the paper, the depth image is simply concatenated to the noisy foreground, so the
network sees 3 + 1 input channels and predicts the 3-channel noise (or x0 / v, see config).
Sizes are named presets (a table, not code) because the right size depends on the hardware:
``cpu`` is sized for a 2-core laptop (about 1.1 M parameters), ``paper`` is the paper-class
network for GPUs.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from diffusers import UNet2DModel

FOREGROUND_CHANNELS = 3
CONDITION_CHANNELS = 1


@dataclass(frozen=True)
class UNetSpec:
    """The few UNet2DModel arguments that set its size; the rest are fixed below."""

    block_out_channels: tuple[int, ...]
    layers_per_block: int
    down_block_types: tuple[str, ...]
    up_block_types: tuple[str, ...]
    add_attention: bool = False
    norm_num_groups: int = 8
    attention_head_dim: int = 8


def _plain(levels: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    return ("DownBlock2D",) * levels, ("UpBlock2D",) * levels


PRESETS: dict[str, UNetSpec] = {
    # CI and contract tests: a few thousand parameters, milliseconds a step.
    "tiny": UNetSpec((8, 16), 1, *_plain(2), norm_num_groups=4),
    # Sized for a laptop CPU: about 1.1 M parameters, no attention.
    "cpu": UNetSpec((32, 64, 64), 1, *_plain(3)),
    # Half the channels at the two full-resolution levels: 0.62 M parameters; in fp32 on an
    # AVX2 CPU it trains 2.5x and samples 2.7x faster than "cpu" (see docs/results/bench.md).
    "cpu-small": UNetSpec((16, 32, 64), 1, *_plain(3)),
    # 6.3 M parameters: 2 ResNet blocks a stage, attention at 16 x 16 (for 64 x 64).
    "medium": UNetSpec(
        (32, 64, 128, 128),
        2,
        ("DownBlock2D", "DownBlock2D", "AttnDownBlock2D", "DownBlock2D"),
        ("UpBlock2D", "AttnUpBlock2D", "UpBlock2D", "UpBlock2D"),
        add_attention=True,
        norm_num_groups=32,
    ),
    # The paper's network, for GPUs (Tactile-Diffusion's YCB-Slide config): channel
    # multipliers 1-2-4-8 on a 64-channel base, 2 ResNet blocks a level, self-attention at
    # the 32 x 32 level of a 64 x 64 input.
    "paper": UNetSpec(
        (64, 128, 256, 512),
        2,
        ("DownBlock2D", "AttnDownBlock2D", "DownBlock2D", "DownBlock2D"),
        ("UpBlock2D", "UpBlock2D", "AttnUpBlock2D", "UpBlock2D"),
        add_attention=True,
        norm_num_groups=32,
    ),
}


def build_unet(spec: UNetSpec, sample_size: int = 64) -> UNet2DModel:
    """A conditional denoiser: (noisy foreground, depth) -> predicted noise."""
    return UNet2DModel(
        sample_size=sample_size,
        in_channels=FOREGROUND_CHANNELS + CONDITION_CHANNELS,
        out_channels=FOREGROUND_CHANNELS,
        **asdict(spec),
    )


def conditional_output(
    unet: UNet2DModel, noisy: torch.Tensor, condition: torch.Tensor, timesteps: torch.Tensor
) -> torch.Tensor:
    """The network's prediction (noise, by default) with the condition concatenated on channels."""
    return unet(torch.cat([noisy, condition.to(noisy.dtype)], dim=1), timesteps).sample


def count_parameters(module: torch.nn.Module) -> int:
    """Number of trainable parameters (for reports and preset sizing)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
