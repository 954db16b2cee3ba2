"""Lightning wrapper of the braille classifier: loss, optimiser, metrics, optional augmentation."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import lightning as L
import torch
from torch import nn
from torchmetrics.classification import (
    MulticlassAccuracy,
    MulticlassConfusionMatrix,
    MulticlassPrecision,
    MulticlassRecall,
)

from tactile_bench.classify.model import NUM_CLASSES, ResNetClassifier


def random_shift(
    x: torch.Tensor, max_px: int, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Translate each image by up to ``max_px`` pixels (replicate padding), vectorised.

    A light augmentation for contact-position error; off by default because the paper's
    classifier had none beyond its data.
    """
    if max_px <= 0:
        return x
    n, _, h, w = x.shape
    padded = nn.functional.pad(x, (max_px,) * 4, mode="replicate")
    dx = torch.randint(0, 2 * max_px + 1, (n,), generator=generator, device=x.device)
    dy = torch.randint(0, 2 * max_px + 1, (n,), generator=generator, device=x.device)
    rows = dy[:, None] + torch.arange(h, device=x.device)[None, :]  # (n, h)
    cols = dx[:, None] + torch.arange(w, device=x.device)[None, :]  # (n, w)
    idx_n = torch.arange(n, device=x.device)[:, None, None]
    out = padded.permute(0, 2, 3, 1)[idx_n, rows[:, :, None], cols[:, None, :]]
    return out.permute(0, 3, 1, 2).contiguous()


class BrailleClassifier(L.LightningModule):
    """ResNet classifier of 64 x 64 foregrounds into 27 braille characters.

    Paper: ResNet-18, Adam lr 1e-4, batch 20, cross-entropy. ``channels_last`` stores the
    network's weights NHWC, so activations follow: with ``precision="bf16-mixed"`` the
    fastest layout on a CPU with bf16 arithmetic (``python -m tactile_bench bench``).
    Metrics follow the paper's table: micro accuracy, macro precision and macro recall
    (torchmetrics), plus the confusion matrix on test (kept in ``self.test_confusion``
    after ``trainer.test``).
    """

    def __init__(
        self,
        num_classes: int = NUM_CLASSES,
        in_channels: int = 3,
        width: int = 16,
        blocks: Sequence[int] = (2, 2, 2, 2),
        stem: str = "light",
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        augment: bool = False,
        shift_px: int = 2,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = ResNetClassifier(
            num_classes=num_classes,
            in_channels=in_channels,
            width=width,
            blocks=tuple(blocks),
            stem=stem,
        )
        if channels_last:  # NHWC weights: oneDNN then keeps activations NHWC (bench: faster)
            self.net = self.net.to(memory_format=torch.channels_last)
        self.loss_fn = nn.CrossEntropyLoss()
        self.train_acc = MulticlassAccuracy(num_classes, average="micro")
        self.val_acc = MulticlassAccuracy(num_classes, average="micro")
        self.test_acc = MulticlassAccuracy(num_classes, average="micro")
        self.test_precision = MulticlassPrecision(num_classes, average="macro")
        self.test_recall = MulticlassRecall(num_classes, average="macro")
        self.test_confmat = MulticlassConfusionMatrix(num_classes)
        self.test_confusion: torch.Tensor | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (N, num_classes) for foregrounds (N, C, S, S)."""
        return self.net(x)

    def training_step(
        self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int
    ) -> torch.Tensor:
        x, y = batch
        if self.hparams.augment:
            x = random_shift(x, int(self.hparams.shift_px))
        logits = self(x)
        loss = self.loss_fn(logits, y)
        self.train_acc(logits.detach(), y)
        # the epoch's mean over every process under DDP (one scalar all-reduce a step)
        self.log("train_loss", loss, prog_bar=True, on_step=True, on_epoch=True, sync_dist=True)
        self.log("train_acc", self.train_acc, prog_bar=True, on_step=False, on_epoch=True)
        return loss

    def validation_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> None:
        x, y = batch
        logits = self(x)
        self.val_acc(logits, y)
        self.log("val_loss", self.loss_fn(logits, y), prog_bar=False, on_epoch=True, sync_dist=True)
        self.log("val_acc", self.val_acc, prog_bar=True, on_epoch=True)

    def test_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> None:
        x, y = batch
        logits = self(x)
        self.test_acc(logits, y)
        self.test_precision(logits, y)
        self.test_recall(logits, y)
        self.test_confmat.update(logits, y)
        self.log("test_acc", self.test_acc, on_epoch=True)
        self.log("test_precision", self.test_precision, on_epoch=True)
        self.log("test_recall", self.test_recall, on_epoch=True)

    def on_test_epoch_end(self) -> None:
        self.test_confusion = self.test_confmat.compute().cpu()
        self.test_confmat.reset()

    def predict_step(self, batch: Any, batch_idx: int) -> torch.Tensor:
        x = batch[0] if isinstance(batch, list | tuple) else batch
        return self(x).argmax(dim=1)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(
            self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay
        )
