"""A trained braille classifier on disk: its final weights and the hyperparameters to rebuild it."""

from __future__ import annotations

from pathlib import Path

import torch

from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.io import atomic_torch_save


def save_classifier(model: BrailleClassifier, path: Path) -> Path:
    """The final weights (after BatchNorm re-estimation) with the hyperparameters to rebuild."""
    return atomic_torch_save(
        {"hparams": dict(model.hparams), "state_dict": model.state_dict()}, path
    )


def load_classifier(path: Path) -> BrailleClassifier:
    """Rebuild a classifier written by ``save_classifier``, in eval mode."""
    payload = torch.load(path, map_location="cpu", weights_only=True)
    model = BrailleClassifier(**payload["hparams"])
    model.load_state_dict(payload["state_dict"])
    return model.eval()
