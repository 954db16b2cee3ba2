"""A LightningDataModule over in-memory (foreground, label) tensors.

The classifier sets (10,692 images of 64 x 64 x 3 float32, about 0.5 GB) fit in memory, so
there is no on-disk dataset here: stages build tensors and hand them over. Shuffling and the
optional train/val split are seeded so a rerun with the same seed sees the same batches.
"""

from __future__ import annotations

import lightning as L
import torch
from torch.utils.data import DataLoader, TensorDataset

Pair = tuple[torch.Tensor, torch.Tensor]


def _as_pair(pair: Pair, what: str) -> Pair:
    x, y = pair
    if x.ndim != 4:
        raise ValueError(f"{what}: images must be (N, C, S, S), got shape {tuple(x.shape)}")
    if y.ndim != 1 or y.shape[0] != x.shape[0]:
        raise ValueError(f"{what}: labels must be (N,) with N={x.shape[0]}, got {tuple(y.shape)}")
    x = x if x.is_floating_point() else x.float()
    return x, y.long()


def stratified_split(
    labels: torch.Tensor, fraction: float, seed: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices (keep, held_out): ``fraction`` of each class held out, chosen by ``seed``.

    Stratified so that a small val set still holds every character.
    """
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {fraction}")
    g = torch.Generator().manual_seed(seed)
    keep, held = [], []
    for c in torch.unique(labels):
        idx = torch.nonzero(labels == c).flatten()
        idx = idx[torch.randperm(idx.numel(), generator=g)]
        k = int(round(fraction * idx.numel()))
        held.append(idx[:k])
        keep.append(idx[k:])
    return torch.cat(keep).sort().values, torch.cat(held).sort().values


class ForegroundDataModule(L.LightningDataModule):
    """Train / val / test loaders over in-memory foreground tensors.

    Args:
        train: (foregrounds (N, C, S, S) float, labels (N,) int).
        val: optional held-out pair; if None and ``val_fraction > 0``, a stratified,
            seeded fraction of ``train`` becomes the val set.
        test: optional pair for ``trainer.test``.
        batch_size: paper: 20.
        num_workers: 0 by default (data are already tensors; workers only cost start-up).
        seed: seeds the shuffling of train batches and the val split.
    """

    def __init__(
        self,
        train: Pair,
        val: Pair | None = None,
        test: Pair | None = None,
        batch_size: int = 20,
        num_workers: int = 0,
        seed: int = 0,
        val_fraction: float = 0.0,
        eval_batch_size: int = 256,
    ) -> None:
        super().__init__()
        x, y = _as_pair(train, "train")
        if val is None and val_fraction > 0:
            keep, held = stratified_split(y, val_fraction, seed)
            val = (x[held], y[held])
            x, y = x[keep], y[keep]
        self.train_set = TensorDataset(x, y)
        self.val_set = TensorDataset(*_as_pair(val, "val")) if val is not None else None
        self.test_set = TensorDataset(*_as_pair(test, "test")) if test is not None else None
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size
        self.num_workers = num_workers
        self.seed = seed

    def train_dataloader(self) -> DataLoader:
        return DataLoader(
            self.train_set,
            batch_size=self.batch_size,
            shuffle=True,
            num_workers=self.num_workers,
            generator=torch.Generator().manual_seed(self.seed),
            persistent_workers=self.num_workers > 0,
        )

    def _eval_loader(self, ds: TensorDataset | None) -> DataLoader:
        if ds is None:
            return []  # type: ignore[return-value]  # Lightning skips empty loaders
        return DataLoader(ds, batch_size=self.eval_batch_size, num_workers=self.num_workers)

    def val_dataloader(self) -> DataLoader:
        return self._eval_loader(self.val_set)

    def test_dataloader(self) -> DataLoader:
        return self._eval_loader(self.test_set)


def stratified_subset(labels: torch.Tensor, fraction: float, seed: int) -> torch.Tensor:
    """Sorted indices of ``fraction`` of each class (at least one), chosen by ``seed``.

    The paper's "x% of the real fine-tuning data": every consumer (translator fine-tuning,
    classifier fine-tuning) that asks with the same seed gets the same subset.
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    g = torch.Generator().manual_seed(seed)
    keep = []
    for c in torch.unique(labels):
        idx = torch.nonzero(labels == c).flatten()
        idx = idx[torch.randperm(idx.numel(), generator=g)]
        keep.append(idx[: max(1, int(round(fraction * idx.numel())))])
    return torch.cat(keep).sort().values
