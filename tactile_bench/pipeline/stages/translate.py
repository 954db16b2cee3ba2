"""Stage ``translate``: fit a registered translator on real pairs, then translate braille sets."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from tactile_bench.data.braille import BrailleSet
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_npz
from tactile_bench.pipeline.loggers import make_loggers
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.translators import create_translator, translator_class


class TranslateConfig(StageConfig):
    """Which translator, how much of the real fine-tuning pool it fits on, what it translates."""

    translator: str = "sim"
    translator_config: dict[str, Any] = {}
    fit_fraction: float = Field(default=0.0, ge=0.0, le=1.0)
    sets: list[Literal["finetune", "test", "classifier"]] = ["classifier"]
    background: Literal["sim", "real"] = "sim"
    batch_size: int = Field(default=512, ge=1)


def _check(config: TranslateConfig, base_dir: Path) -> None:
    try:
        cls = translator_class(config.translator)
        cls.parse_config(config.translator_config)
    except TactileBenchError as exc:
        raise TactileBenchError(f"translator: {exc}") from None


def _fit_subset(pool: BrailleSet, fraction: float, seed: int) -> BrailleSet:
    """A stratified fraction of the fine-tuning pool, the same for every translator."""
    gen = torch.Generator().manual_seed(seed)
    keep = []
    for label in torch.unique(pool.labels):
        idx = torch.nonzero(pool.labels == label).flatten()
        idx = idx[torch.randperm(len(idx), generator=gen)]
        keep.append(idx[: max(1, round(fraction * len(idx)))])
    return pool.subset(torch.sort(torch.cat(keep)).values)


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: TranslateConfig = ctx.config
    data = ctx.input("data")
    translator = create_translator(config.translator, config.translator_config)
    metrics: dict[str, Any] = {"translator": config.translator}
    if translator.trainable and config.fit_fraction > 0:
        pairs = _fit_subset(BrailleSet.load(data.path("finetune")), config.fit_fraction, ctx.seed)
        translator.fit_pairs(
            pairs.depth,
            pairs.foreground("real"),
            ctx.directory,
            ctx.trainer,
            loggers=make_loggers(ctx.directory, f"{ctx.name}-{config.translator}"),
        )
        metrics["fit_pairs"] = len(pairs)
    translator.save(ctx.directory / "translator.pt")
    outputs = {"translator": "translator.pt"}
    gen = torch.Generator().manual_seed(ctx.seed)
    for name in config.sets:
        split = BrailleSet.load(data.path(name))
        background = torch.from_numpy(
            np.asarray(
                split.sim_background if config.background == "sim" else split.real_background
            )
        ).float()
        chunks = [
            translator.translate(split.depth[i : i + config.batch_size], background, gen)
            for i in range(0, len(split), config.batch_size)
        ]
        images = torch.cat(chunks).round().clamp(0, 255).to(torch.uint8)
        atomic_write_npz(
            ctx.directory / f"{name}.npz",
            images=images.numpy(),
            background=background.round().to(torch.uint8).numpy(),
            labels=split.labels.numpy(),
        )
        outputs[name] = f"{name}.npz"
    return outputs, metrics


STAGE = StageKind(
    name="translate",
    description="fit a translator on real pairs (optional) and translate braille depth to images",
    config_model=TranslateConfig,
    run=_run,
    input_slots={"data": True},
    check=_check,
)
