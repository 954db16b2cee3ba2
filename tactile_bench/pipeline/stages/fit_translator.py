"""Stage ``fit_translator``: fit a registered translator on real pairs, optionally from a
previous fit (pretrain on a corpus, then fine-tune on a fraction of the braille pool) or from
a checkpoint file (``init_checkpoint``: e.g. a model someone else fitted).

The fit checkpoints itself in ``<stage dir>/checkpoints/last.ckpt``; a killed run resumes there.
``metrics.json`` holds what the fit produced (held-out scores, ``divergence`` of a GAN); the
stage's returned metrics add ``resumed_from_step``, which is not an output (an interrupted and
an uninterrupted run write the same files)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.corpus import load_pairs
from tactile_bench.data.datamodule import stratified_subset
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_json
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.pipeline.loggers import finish_loggers, make_loggers
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    resolve_source,
)
from tactile_bench.translators import Translator, create_translator, translator_class


class FitTranslatorConfig(StageConfig):
    """Which translator, its config, and which share of the braille fine-tuning pool it sees."""

    translator: str = Field(description="registered translator name (see `list translators`)")
    translator_config: dict[str, Any] = Field(
        default={}, description="the translator's own config (its keys: its config class)"
    )
    fraction: float = Field(
        default=1.0, gt=0.0, le=1.0, description="share of the training pairs to fit on"
    )
    train_set: Literal["finetune", "split_train"] = Field(
        default="finetune",
        description="braille pairs to fit on: the fine-tuning pool, or (real data) the "
        "translator split's train list, as train_braille.py trains",
    )
    eval_pairs: int = Field(
        default=64, ge=0, description="held-out test pairs scored (SSIM, MSE) at the end; 0: none"
    )
    init_checkpoint: str | None = Field(
        default=None,
        description="start from this translator file (relative to the recipe) instead of an "
        "init stage",
    )


def recipe_translator_config(name: str, config: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """``config`` with the translator's file keys (its ``path_keys``, e.g. ``profile``'s
    ``profile``) read from the recipe's folder, as every path in a recipe is; a value
    without a suffix is a name (a built-in profile), not a path."""
    out = dict(config)
    for key in getattr(translator_class(name), "path_keys", ()):
        value = out.get(key)
        if isinstance(value, str) and Path(value).suffix:
            out[key] = str(resolve_source(value, base_dir))
    return out


def _check(config: FitTranslatorConfig, base_dir: Path) -> None:
    try:
        kind = translator_class(config.translator)
        kind.parse_config(
            recipe_translator_config(config.translator, config.translator_config, base_dir)
        )
    except TactileBenchError as exc:
        raise TactileBenchError(f"translator: {exc}") from None
    if config.init_checkpoint is not None:
        try:  # the whole file: a checkpoint of another translator or version fails here
            kind.load(resolve_source(config.init_checkpoint, base_dir))
        except TactileBenchError as exc:
            raise TactileBenchError(f"init_checkpoint: {exc}") from None


def load_fitted(ctx: StageContext, slot: str) -> Translator | None:
    """The translator a ``fit_translator`` stage wrote, if ``slot`` is connected."""
    result = ctx.optional_input(slot)
    if result is None:
        return None
    kind = translator_class(result.metrics["translator"])
    return kind.load(result.path("translator"))


def _pairs(
    ctx: StageContext, fraction: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Train depth and foreground; held-out depth, real images and background(s)."""
    braille, corpus = ctx.optional_input("braille"), ctx.optional_input("corpus")
    train_set = ctx.config.train_set
    if braille is not None and train_set not in braille.outputs:
        raise TactileBenchError(
            f"stage {ctx.name}: train_set: {train_set} needs a braille_data stage with a "
            f"real-data source; {braille.name!r} has {', '.join(sorted(braille.outputs))}"
        )
    if braille is not None:
        pool = BrailleSet.load(braille.path(train_set))
        if train_set == "finetune" and "finetune_in_test" in braille.outputs:
            # real data: the pool holds the split's test files; fit without them
            in_test = np.load(braille.path("finetune_in_test"))
            pool = pool.subset(torch.from_numpy(~in_test))
        pool = pool.subset(stratified_subset(pool.labels, fraction, ctx.seed))
        test = BrailleSet.load(braille.path("test"))
        return (
            pool.depth,
            pool.foreground("real"),
            test.depth,
            test.real,
            test.real_background.float(),
        )
    train, test = load_pairs(corpus.directory, "train"), load_pairs(corpus.directory, "test")
    return (
        train.depth,
        train.foreground("real"),
        test.depth,
        test.real,
        test.real_background[test.real_bg_index].float(),
    )


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: FitTranslatorConfig = ctx.config
    previous = load_fitted(ctx, "init")
    if previous is not None and config.init_checkpoint is not None:
        raise TactileBenchError(
            f"stage {ctx.name}: give init (an earlier stage) or init_checkpoint, not both"
        )
    if config.init_checkpoint is not None:
        previous = translator_class(config.translator).load(
            resolve_source(config.init_checkpoint, ctx.recipe_dir)
        )
    translator = create_translator(
        config.translator,
        recipe_translator_config(config.translator, config.translator_config, ctx.recipe_dir),
    )
    if previous is not None:
        if type(previous) is not type(translator):
            raise TactileBenchError(
                f"stage {ctx.name}: init is a {previous.name!r} translator, not {translator.name!r}"
            )
        translator.load_state_dict(previous.state_dict())
    depth, foreground, test_depth, test_real, test_bg = _pairs(ctx, config.fraction)
    loggers = make_loggers(ctx.directory, f"{ctx.name}-{config.translator}")
    try:
        report = translator.fit_pairs(
            depth, foreground, ctx.directory, ctx.trainer, loggers=loggers
        )
    finally:  # wandb keeps one run a process: the next stage's fit would log into this one
        finish_loggers(loggers)
    translator.save(ctx.directory / "translator.pt")

    init_from = None
    if config.init_checkpoint is not None:
        init_from = config.init_checkpoint
    elif previous is not None:
        init_from = ctx.inputs["init"][0].name
    diagnostics = translator.fit_diagnostics()
    metrics: dict[str, Any] = {
        "translator": config.translator,
        "fit_pairs": len(depth),
        "initialised_from": init_from,
        "divergence": diagnostics.get("divergence"),
        # what the fit found (e.g. calibrated's selected effects and fit seconds); {}: nothing
        "fit": diagnostics,
        # the precision the fit trained in (None: nothing was trained)
        "compute_precision": translator.training_precision(ctx.trainer) if report else None,
    }
    n = min(config.eval_pairs, len(test_depth))
    if n:
        idx = torch.randperm(len(test_depth), generator=torch.Generator().manual_seed(ctx.seed))[:n]
        bg = test_bg if test_bg.dim() == 3 else test_bg[idx]
        pred = translator.translate(test_depth[idx], bg, torch.Generator().manual_seed(ctx.seed))
        metrics["heldout"] = {"n": n, **ssim_mse(pred, test_real[idx].float())}
    atomic_write_json(ctx.directory / "metrics.json", metrics)
    resumed = report.resumed_from_step if report is not None else None
    return {"translator": "translator.pt", "metrics": "metrics.json"}, {
        **metrics,
        "resumed_from_step": resumed,
    }


STAGE = StageKind(
    name="fit_translator",
    description="fit a translator on real pairs (braille pool fraction or a corpus), "
    "optionally starting from an earlier fit",
    config_model=FitTranslatorConfig,
    run=_run,
    input_slots={"braille": False, "corpus": False, "init": False},
    exactly_one_of=("braille", "corpus"),
    check=_check,
    precision_dependent=True,
    fits=True,
)
