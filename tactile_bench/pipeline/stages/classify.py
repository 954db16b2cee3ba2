"""Stage ``classify``: train braille classifiers (one per seed) and test them on real images."""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from tactile_bench.classify.train import ClassifierConfig, evaluate, train_classifier
from tactile_bench.data.braille import BrailleSet
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.io import atomic_write_json, load_npz
from tactile_bench.pipeline.loggers import make_loggers
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.report.figures import confusion_png, per_class_bar_png
from tactile_bench.translators import image_to_foreground


class ClassifierSettings(StageConfig):
    """The classifier's architecture and optimisation (see classify.train.ClassifierConfig)."""

    width: int = Field(default=16, ge=1)
    blocks: tuple[int, int, int, int] = (2, 2, 2, 2)
    lr: float = Field(default=1e-3, gt=0)
    batch_size: int = Field(default=20, ge=1)
    epochs: int = Field(default=10, ge=1)
    precision: Literal["32-true", "bf16-mixed"] = "32-true"


class ClassifyConfig(StageConfig):
    """Which row of the table this is, what it trains on, and over which seeds."""

    row: str
    train_images: Literal["translated", "sim", "real"] = "translated"
    seeds: list[int] = Field(default=[0], min_length=1)
    heldout_fraction: float = Field(default=0.1, ge=0.0, lt=1.0)
    classifier: ClassifierSettings = ClassifierSettings()


def _stratified_split(
    labels: torch.Tensor, fraction: float, seed: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Train / held-out indices, the same fraction of every class."""
    gen = torch.Generator().manual_seed(seed)
    train, held = [], []
    for label in torch.unique(labels):
        idx = torch.nonzero(labels == label).flatten()
        idx = idx[torch.randperm(len(idx), generator=gen)]
        n_held = round(fraction * len(idx))
        held.append(idx[:n_held])
        train.append(idx[n_held:])
    return torch.cat(train), torch.cat(held)


def _training_foreground(ctx: StageContext) -> tuple[torch.Tensor, torch.Tensor]:
    config: ClassifyConfig = ctx.config
    if config.train_images == "translated":
        arrays = load_npz(
            ctx.input("images").path("classifier"), ("images", "background", "labels")
        )
        images = torch.from_numpy(arrays["images"]).float()
        background = torch.from_numpy(arrays["background"]).float()
        return image_to_foreground(images, background), torch.from_numpy(arrays["labels"])
    split = BrailleSet.load(ctx.input("data").path("classifier"))
    return split.foreground(config.train_images), split.labels


def _summary(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=float)
    return {"mean": float(arr.mean()), "std": float(arr.std(ddof=1)) if len(arr) > 1 else 0.0}


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: ClassifyConfig = ctx.config
    foreground, labels = _training_foreground(ctx)
    test = BrailleSet.load(ctx.input("data").path("test"))
    test_fg = test.foreground("real")
    n_classes = int(max(labels.max(), test.labels.max())) + 1
    classes = list(CHARACTERS[:n_classes])

    per_seed = []
    for seed in config.seeds:
        train_idx, held_idx = _stratified_split(labels, config.heldout_fraction, seed)
        settings = ClassifierConfig(**config.classifier.model_dump(), seed=seed)
        seed_dir = ctx.directory / f"seed{seed}"
        model = train_classifier(
            foreground[train_idx],
            labels[train_idx],
            settings,
            seed_dir,
            loggers=make_loggers(seed_dir, f"{ctx.name}-seed{seed}"),
            trainer_kwargs=ctx.trainer,
            num_classes=n_classes,
        )
        real = evaluate(model, test_fg, test.labels, num_classes=n_classes)
        heldout = (
            evaluate(model, foreground[held_idx], labels[held_idx], num_classes=n_classes)
            if len(held_idx)
            else None
        )
        per_seed.append({"seed": seed, "test": real, "heldout": heldout})

    first = per_seed[0]["test"]
    confusion_png(
        first["confusion"],
        classes,
        ctx.directory / "confusion.png",
        title=f"{config.row}: confusion on real test (seed {config.seeds[0]})",
    )
    per_class_bar_png(first["per_class_accuracy"], classes, ctx.directory / "per_class.png")
    summary = {
        "row": config.row,
        "train_images": config.train_images,
        "seeds": config.seeds,
        "n_train": int(len(labels) - len(held_idx)),
        "n_test": int(len(test)),
        **{
            m: _summary([s["test"][m] for s in per_seed])
            for m in ("accuracy", "precision", "recall")
        },
        "heldout_accuracy": (
            _summary([s["heldout"]["accuracy"] for s in per_seed])
            if per_seed[0]["heldout"]
            else None
        ),
    }
    atomic_write_json(ctx.directory / "metrics.json", {"summary": summary, "per_seed": per_seed})
    outputs = {
        "metrics": "metrics.json",
        "confusion": "confusion.png",
        "per_class": "per_class.png",
    }
    return outputs, summary


STAGE = StageKind(
    name="classify",
    description="train braille classifiers over seeds, test on the real test set",
    config_model=ClassifyConfig,
    run=_run,
    input_slots={"data": True, "images": False},
)
