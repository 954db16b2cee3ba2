"""A ResNet-18-topology classifier for 64 x 64 tactile foregrounds, trained from scratch.

The paper uses an ImageNet ResNet-18 (base width 64). Nothing may download weights here,
and the table needs 27 trainings on 2 CPU cores, so the topology is kept (BasicBlocks,
BatchNorm, four stages that halve resolution and double width) while the base ``width`` and
the ``stem`` are configurable:

- ``"light"`` (default): one 3 x 3 stride-2 conv, no max-pool: stages run at 32, 16, 8, 4 px.
- ``"cifar"``: 3 x 3 stride 1, no pool (stages at 64 .. 8 px; 4x the FLOPs of "light").
- ``"imagenet"``: torchvision's 7 x 7 stride 2 + max-pool (stages at 16 .. 2 px).

Forward FLOPs per 64 x 64 RGB image, counted by ``torch.utils.flop_counter.FlopCounterMode``
(FLOPs = 2 x multiply-accumulates; a training step costs about 3x):

| width | blocks    | stem     | params  | forward FLOPs |
| ----- | --------- | -------- | ------- | ------------- |
| 64    | (2,2,2,2) | imagenet | 11.19 M | 0.30 GFLOP    |
| 64    | (2,2,2,2) | light    | 11.18 M | 1.11 GFLOP    |
| 64    | (2,2,2,2) | cifar    | 11.18 M | 4.44 GFLOP    |
| 16    | (2,2,2,2) | cifar    | 0.70 M  | 280 MFLOP     |
| 16    | (2,2,2,2) | light    | 0.70 M  | 70 MFLOP      |  <- CPU default
| 16    | (1,1,1,1) | light    | 0.31 M  | 32 MFLOP      |
| 8     | (2,2,2,2) | light    | 0.18 M  | 18 MFLOP      |

Measured training step (Adam, batch 20, 64 x 64, 2 threads, idle machine): the default
286 img/s fp32 and 447 img/s with bf16 autocast (batch 64: 466 / 713); width 16 with the
"cifar" stem 120 / 197; width 64 "imagenet" (the paper's net) 54 / 115.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

NUM_CLASSES = 27


class BasicBlock(nn.Module):
    """Two 3 x 3 convs with BatchNorm and an identity (or 1 x 1 projection) shortcut."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_ch != out_ch:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_ch, out_ch, 1, stride=stride, bias=False), nn.BatchNorm2d(out_ch)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + self.shortcut(x))


class ResNetClassifier(nn.Module):
    """ResNet-18 topology with a configurable base width, for (N, C, S, S) foregrounds.

    Args:
        num_classes: output logits (27 braille characters: A-Z and #).
        in_channels: 3 for RGB foregrounds, 1 for depth.
        width: channels of the first stage; stage ``i`` has ``width * 2**i``. Paper: 64.
        blocks: BasicBlocks per stage; ResNet-18 is (2, 2, 2, 2).
        stem: ``"cifar"`` (3 x 3 stride 1, no pool; keeps 64 x 64 detail) or ``"imagenet"``
            (7 x 7 stride 2 plus 3 x 3 max-pool, as torchvision's ResNet-18).
    """

    def __init__(
        self,
        num_classes: int = NUM_CLASSES,
        in_channels: int = 3,
        width: int = 16,
        blocks: Sequence[int] = (2, 2, 2, 2),
        stem: str = "cifar",
    ) -> None:
        super().__init__()
        if width < 1 or not blocks or any(b < 1 for b in blocks):
            raise ValueError(f"width must be >= 1 and blocks positive, got {width}, {blocks}")
        if stem == "cifar":
            self.stem = nn.Sequential(
                nn.Conv2d(in_channels, width, 3, stride=1, padding=1, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            )
        elif stem == "light":
            self.stem = nn.Sequential(
                nn.Conv2d(in_channels, width, 3, stride=2, padding=1, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            )
        elif stem == "imagenet":
            self.stem = nn.Sequential(
                nn.Conv2d(in_channels, width, 7, stride=2, padding=3, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
                nn.MaxPool2d(3, stride=2, padding=1),
            )
        else:
            raise ValueError(f"stem must be 'cifar', 'light' or 'imagenet', got {stem!r}")
        layers: list[nn.Module] = []
        in_ch = width
        for i, n in enumerate(blocks):
            out_ch = width * 2**i
            for j in range(n):
                layers.append(BasicBlock(in_ch, out_ch, stride=2 if (i > 0 and j == 0) else 1))
                in_ch = out_ch
        self.layers = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Linear(in_ch, num_classes)
        self._init_weights()

    def _init_weights(self) -> None:
        """He init for convs; zero the last BN of each block so blocks start as identities."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for m in self.modules():
            if isinstance(m, BasicBlock):
                nn.init.zeros_(m.bn2.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (N, num_classes) for inputs (N, in_channels, S, S)."""
        return self.fc(torch.flatten(self.pool(self.layers(self.stem(x))), 1))


def count_flops(model: nn.Module, size: int = 64, in_channels: int = 3) -> int:
    """Forward FLOPs for one ``size`` x ``size`` image, counted by FlopCounterMode."""
    from torch.utils.flop_counter import FlopCounterMode

    was_training = model.training
    model.eval()
    x = torch.zeros(1, in_channels, size, size)
    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        model(x)
    model.train(was_training)
    return int(counter.get_total_flops())
