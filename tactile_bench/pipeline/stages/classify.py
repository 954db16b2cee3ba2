"""Stage ``classify``: train braille classifiers (one per seed) and test them on real images.

A row of the paper's table is: train on some images (sim, translated, or real) or start from
another classify stage's models (input ``init``, same seeds), optionally fine-tune on a
fraction of the real fine-tuning pool, test on the real classifier test set
(upright, off-grid contacts). The same test contacts rendered by the simulator give the
accuracy on sim at identical poses: the difference between the two is the sensor's reality
gap alone, with no pose shift mixed in. A held-out part of the training images is scored too,
and, when the data stage has a ``second_unit``, the same test contacts rendered by that unit.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from tactile_bench.classify.store import load_classifier, save_classifier
from tactile_bench.classify.train import (
    ClassifierConfig,
    batchable,
    classifier_precision,
    evaluate,
    train_classifier,
    train_classifiers,
)
from tactile_bench.data.braille import SECOND_UNIT_SET, BrailleSet
from tactile_bench.data.datamodule import stratified_split, stratified_subset
from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import Precision, compute_device
from tactile_bench.io import atomic_write_json, load_npz
from tactile_bench.pipeline.loggers import make_loggers
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    StageResult,
)
from tactile_bench.pipeline.stages.paired_data import class_names
from tactile_bench.pools import cancel_pending, forget_kept_pool, kept_pool
from tactile_bench.report.figures import confusion_png, per_class_bar_png
from tactile_bench.translators import image_to_foreground

log = logging.getLogger("tactile_bench")


class ClassifierSettings(StageConfig):
    """The classifier's architecture and optimisation (see classify.train.ClassifierConfig)."""

    width: int = Field(default=16, ge=1, description="channels of the ResNet's first stage")
    blocks: tuple[int, int, int, int] = Field(
        default=(2, 2, 2, 2), description="residual blocks per stage (ResNet-18: 2, 2, 2, 2)"
    )
    lr: float = Field(default=1e-3, gt=0, description="Adam learning rate")
    batch_size: int = Field(default=20, ge=1, description="images a step")
    epochs: int = Field(default=4, ge=1, description="epochs of the base training")
    precision: Precision = Field(
        default="auto", description="auto: bf16 where the CPU has bf16 arithmetic, else fp32"
    )


class ClassifyConfig(StageConfig):
    """Which row of the table this is, what it trains on, and over which seeds."""

    row: str = Field(description="the row of the table this stage fills (e.g. Sim)")
    train_images: Literal["translated", "sim", "real"] = Field(
        default="translated", description="images trained on: a translate stage's, sim or real"
    )
    # sim_release: the release's TACTO frames (braille_data sim_source: release), train_images: sim
    train_set: Literal["classifier", "finetune", "sim_release"] = Field(
        default="classifier", description="braille set trained on"
    )
    finetune_fraction: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="share of the real fine-tuning pool to fine-tune on afterwards; 0: none",
    )
    finetune_epochs: int = Field(default=4, ge=1, description="epochs of that fine-tuning")
    seeds: list[int] = Field(
        default=[0], min_length=1, description="one classifier a seed; the table gives mean +- std"
    )
    parallel_seeds: int = Field(
        default=1,
        ge=1,
        description="with batch_seeds false: seeds trained at once, each in its own process "
        "on cores / N threads (a small classifier gains little from a second thread); 1: in "
        "turn, in this process",
    )
    batch_seeds: bool = Field(
        default=True,
        description="train the seeds as one batched model (grouped convolutions, each seed "
        "its own weights, data order and BatchNorm; the same models as one at a time within "
        "float tolerance); false: one model a seed (parallel_seeds applies)",
    )
    heldout_fraction: float = Field(
        default=0.1, ge=0.0, lt=1.0, description="share of the training images held out"
    )
    classifier: ClassifierSettings = Field(
        default=ClassifierSettings(), description="architecture and optimisation"
    )


def _has(ctx: StageContext, split: str, what: str) -> bool:
    """Whether the data stage's ``split`` carries ``what`` ("has_sim"/"has_real")."""
    content = ctx.input("data").metrics.get("content") or {}
    return bool(content.get(split, {}).get(what, True))


def _training_foreground(ctx: StageContext) -> tuple[torch.Tensor, torch.Tensor]:
    config: ClassifyConfig = ctx.config
    if config.train_set == "sim_release" and config.train_images != "sim":
        raise TactileBenchError(
            f"stage {ctx.name}: train_set: sim_release holds the release's TACTO frames: "
            "set train_images: sim"
        )
    if config.train_set not in ctx.input("data").outputs:
        raise TactileBenchError(
            f"stage {ctx.name}: train_set: {config.train_set}: data stage "
            f"{ctx.input('data').name!r} has no such set (sim_release needs braille_data "
            "with a real-data source and sim_source: release)"
        )
    if config.train_images != "translated" and not _has(
        ctx, config.train_set, f"has_{config.train_images}"
    ):
        raise TactileBenchError(
            f"stage {ctx.name}: the {config.train_set!r} set of data stage "
            f"{ctx.input('data').name!r} has no {config.train_images} images (a real-data "
            "source has real images only in 'finetune', 'test' and 'classifier_test'); "
            "set train_set: finetune"
        )
    if config.train_images == "translated":
        arrays = load_npz(
            ctx.input("images").path(config.train_set), ("images", "background", "labels")
        )
        images = torch.from_numpy(arrays["images"]).float()
        background = torch.from_numpy(arrays["background"]).float()
        return image_to_foreground(images, background), torch.from_numpy(arrays["labels"])
    split = BrailleSet.load(ctx.input("data").path(config.train_set))
    return split.foreground(config.train_images), split.labels


def _summary(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=float)
    return {"mean": float(arr.mean()), "std": float(arr.std(ddof=1)) if len(arr) > 1 else 0.0}


def _real_finetune_pool(ctx: StageContext) -> BrailleSet | None:
    """The stratified real fraction classifiers fine-tune on (None when there is none)."""
    config: ClassifyConfig = ctx.config
    if config.finetune_fraction == 0:
        return None
    pool = BrailleSet.load(ctx.input("data").path("finetune"))
    return pool.subset(stratified_subset(pool.labels, config.finetune_fraction, ctx.seed))


def _train_one(
    ctx: StageContext,
    seed: int,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    n_classes: int,
    pool: BrailleSet | None,
) -> tuple[Any, torch.Tensor]:
    """Train (and optionally fine-tune on real) one classifier; returns it and held-out idx.

    With an ``init`` stage the base training is that stage's model of the same seed (a
    fine-tuning row then costs only the fine-tuning, not a second identical base training).
    """
    config: ClassifyConfig = ctx.config
    train_idx, held_idx = stratified_split(labels, config.heldout_fraction, seed)
    seed_dir = ctx.directory / f"seed{seed}"
    init = ctx.optional_input("init")
    if init is not None:
        model = load_classifier(_init_model_path(init, seed))
    else:
        settings = ClassifierConfig(**config.classifier.model_dump(), seed=seed)
        model = train_classifier(
            foreground[train_idx],
            labels[train_idx],
            settings,
            seed_dir,
            loggers=make_loggers(seed_dir, f"{ctx.name}-seed{seed}"),
            trainer_kwargs=ctx.trainer,
            num_classes=n_classes,
        )
    if pool is not None:
        tune = ClassifierConfig(
            **(config.classifier.model_dump() | {"epochs": config.finetune_epochs}), seed=seed
        )
        model = train_classifier(
            pool.foreground("real"),
            pool.labels,
            tune,
            seed_dir / "finetune",
            loggers=make_loggers(seed_dir, f"{ctx.name}-seed{seed}-finetune"),
            trainer_kwargs=ctx.trainer,
            num_classes=n_classes,
            init=model,
        )
    return model, held_idx


def _train_seed_in_worker(
    ctx: StageContext,
    seed: int,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    n_classes: int,
    pool: BrailleSet | None,
    threads: int,
) -> tuple[str, torch.Tensor]:
    """``_train_one`` in a worker process on ``threads`` threads, without progress bars (two
    would interleave); the model goes back through a file, not a pickle of the module."""
    torch.set_num_threads(threads)
    ctx = dataclasses.replace(ctx, trainer={**ctx.trainer, "enable_progress_bar": False})
    model, held_idx = _train_one(ctx, seed, foreground, labels, n_classes, pool)
    path = save_classifier(model, ctx.directory / f"seed{seed}" / "trained.pt")
    return str(path), held_idx


def _train_seeds(
    ctx: StageContext,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    n_classes: int,
    pool: BrailleSet | None,
) -> list[tuple[Any, torch.Tensor]]:
    """Every seed's trained model and held-out indices, ``parallel_seeds`` at a time.

    The workers (``tactile_bench.pools.kept_pool``: spawned once, reused by the run's later
    classify stages, stopped when the run or this worker process ends) train on
    ``threads`` threads each so that together they use the cores this process had. A seed's
    training is the same function with the same arguments in either case, so its weights are
    the same as training it here on that many threads.
    """
    config: ClassifyConfig = ctx.config
    if _batches_seeds(ctx):
        return _train_batched(ctx, foreground, labels, n_classes, pool)
    workers = min(config.parallel_seeds, len(config.seeds))
    if workers <= 1:
        return [_train_one(ctx, seed, foreground, labels, n_classes, pool) for seed in config.seeds]
    threads = max(1, torch.get_num_threads() // workers)
    start = time.perf_counter()
    executor = kept_pool(workers)
    jobs = [
        executor.submit(
            _train_seed_in_worker, ctx, seed, foreground, labels, n_classes, pool, threads
        )
        for seed in config.seeds
    ]
    try:
        done = [job.result() for job in jobs]
    except BrokenProcessPool:
        forget_kept_pool(workers)
        raise TactileBenchError(
            f"stage {ctx.name}: a seed's worker process died (out of memory?); "
            "set parallel_seeds: 1 to train the seeds in turn"
        ) from None
    finally:  # an error or an interrupt: do not leave the pool busy with the other seeds
        cancel_pending(jobs)
    log.info(
        "stage %s: %d seeds trained, %d at a time on %d thread(s) each, in %.1f s",
        ctx.name,
        len(done),
        workers,
        threads,
        time.perf_counter() - start,
    )
    return [(load_classifier(Path(path)), held_idx) for path, held_idx in done]


def _seed_configs(ctx: StageContext, epochs: int | None = None) -> list[ClassifierConfig]:
    """Each seed's classifier settings (``epochs``: a fine-tuning's instead of the base's)."""
    config: ClassifyConfig = ctx.config
    settings = config.classifier.model_dump() | ({"epochs": epochs} if epochs else {})
    return [ClassifierConfig(**settings, seed=seed) for seed in config.seeds]


def _batches_seeds(ctx: StageContext) -> bool:
    """Whether this stage trains its seeds as one batched model (said in the log when the
    config asks for it but the fit cannot, e.g. under a launch of several processes)."""
    config: ClassifyConfig = ctx.config
    if not config.batch_seeds or len(config.seeds) < 2:
        return False
    reason = batchable(_seed_configs(ctx), ctx.trainer)
    if reason is not None:
        log.info("stage %s: seeds trained one at a time: %s", ctx.name, reason)
    return reason is None


def _train_batched(
    ctx: StageContext,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    n_classes: int,
    pool: BrailleSet | None,
) -> list[tuple[Any, torch.Tensor]]:
    """``_train_one`` for every seed at once: one stacked model trains all seeds, each on
    its own training split (the same ones as one at a time), then fine-tunes them together."""
    config: ClassifyConfig = ctx.config
    splits = [stratified_split(labels, config.heldout_fraction, seed) for seed in config.seeds]
    folder = ctx.directory / "seeds"
    init = ctx.optional_input("init")
    start = time.perf_counter()
    if init is not None:
        models = [load_classifier(_init_model_path(init, seed)) for seed in config.seeds]
    else:
        models = train_classifiers(
            foreground,
            labels,
            _seed_configs(ctx),
            folder,
            loggers=make_loggers(folder, f"{ctx.name}-seeds"),
            trainer_kwargs=ctx.trainer,
            num_classes=n_classes,
            subsets=[train_idx for train_idx, _ in splits],
        )
    if pool is not None:
        models = train_classifiers(
            pool.foreground("real"),
            pool.labels,
            _seed_configs(ctx, epochs=config.finetune_epochs),
            folder / "finetune",
            loggers=make_loggers(folder, f"{ctx.name}-seeds-finetune"),
            trainer_kwargs=ctx.trainer,
            num_classes=n_classes,
            inits=models,
        )
    log.info(
        "stage %s: %d seeds trained as one batched model in %.1f s",
        ctx.name,
        len(models),
        time.perf_counter() - start,
    )
    return [(model, held_idx) for model, (_, held_idx) in zip(models, splits, strict=True)]


def _init_model_path(init: StageResult, seed: int) -> Path:
    key = f"model_seed{seed}"
    if key not in init.outputs:
        raise TactileBenchError(
            f"init: stage {init.name!r} has no model for seed {seed} "
            f"(it trained seeds {sorted(k[10:] for k in init.outputs if k.startswith(key[:10]))})"
        )
    return init.path(key)


def _second_unit(ctx: StageContext) -> tuple[str, torch.Tensor, torch.Tensor] | None:
    """The data stage's second unit: its name, and the real foregrounds and labels of the
    classifier test contacts it rendered (None when the data stage has no second unit)."""
    data = ctx.input("data")
    if SECOND_UNIT_SET not in data.outputs:
        return None
    unit = BrailleSet.load(data.path(SECOND_UNIT_SET))
    return str(data.metrics.get("second_unit")), unit.foreground("real"), unit.labels


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: ClassifyConfig = ctx.config
    foreground, labels = _training_foreground(ctx)
    test = BrailleSet.load(ctx.input("data").path("classifier_test"))
    unit = _second_unit(ctx)
    test_fg = test.foreground("real")
    n_classes = int(max(labels.max(), test.labels.max())) + 1
    if n_classes < 2:
        raise TactileBenchError(
            f"stage {ctx.name}: data stage {ctx.input('data').name!r} has one label only; "
            "a classifier needs two or more (a paired folder: one subfolder a label)"
        )
    classes = class_names(ctx.input("data"), n_classes)

    pool = _real_finetune_pool(ctx)
    trained = _train_seeds(ctx, foreground, labels, n_classes, pool)
    per_seed = _score_seeds(ctx, trained, foreground, labels, test, test_fg, unit, n_classes)

    first = per_seed[0]["test"]
    confusion_png(
        first["confusion"],
        classes,
        ctx.directory / "confusion.png",
        title=f"{config.row}: confusion on real test (seed {config.seeds[0]})",
    )
    per_class_bar_png(first["per_class_accuracy"], classes, ctx.directory / "per_class.png")
    # every seed holds out as many images (stratified_split's count does not depend on it)
    n_train = int(len(labels) - len(trained[-1][1]))
    summary = _stage_summary(ctx, per_seed, n_train, int(len(test)), pool, unit)
    atomic_write_json(ctx.directory / "metrics.json", {"summary": summary, "per_seed": per_seed})
    outputs = {
        "metrics": "metrics.json",
        "confusion": "confusion.png",
        "per_class": "per_class.png",
    }
    outputs |= {f"model_seed{seed}": f"model_seed{seed}.pt" for seed in config.seeds}
    return outputs, summary


def _score_seeds(
    ctx: StageContext,
    trained: list[tuple[Any, torch.Tensor]],
    foreground: torch.Tensor,
    labels: torch.Tensor,
    test: BrailleSet,
    test_fg: torch.Tensor,
    unit: tuple[str, torch.Tensor, torch.Tensor] | None,
    n_classes: int,
) -> list[dict[str, Any]]:
    """Each seed's scores on real and sim test, the second unit and its held-out images;
    its model saved as ``model_seed<seed>.pt``."""
    config: ClassifyConfig = ctx.config
    device = compute_device(ctx.trainer.get("accelerator"))
    per_seed = []
    for seed, (model, held_idx) in zip(config.seeds, trained, strict=True):
        model.to(device)  # scored where it trained; saved from the CPU below
        heldout = (
            evaluate(model, foreground[held_idx], labels[held_idx], num_classes=n_classes)
            if len(held_idx)
            else None
        )
        real = evaluate(model, test_fg, test.labels, num_classes=n_classes)
        sim = (
            evaluate(model, test.foreground("sim"), test.labels, num_classes=n_classes)
            if _has(ctx, "classifier_test", "has_sim")
            else None
        )
        on_unit = evaluate(model, *unit[1:], num_classes=n_classes) if unit else None
        per_seed.append(
            {
                "seed": seed,
                "test": real,
                "test_sim": sim,
                "second_unit": on_unit,
                "heldout": heldout,
            }
        )
        save_classifier(model.cpu(), ctx.directory / f"model_seed{seed}.pt")
    return per_seed


def _stage_summary(
    ctx: StageContext,
    per_seed: list[dict[str, Any]],
    n_train: int,
    n_test: int,
    pool: BrailleSet | None,
    unit: tuple[str, torch.Tensor, torch.Tensor] | None,
) -> dict[str, Any]:
    """The row of the table: what was trained on, and mean +- std of every score over seeds."""
    config: ClassifyConfig = ctx.config
    return {
        "row": config.row,
        "train_images": config.train_images,
        "train_set": config.train_set,
        "finetune_fraction": config.finetune_fraction,
        "seeds": config.seeds,
        "n_train": n_train,
        "n_finetune": len(pool) if pool is not None else 0,  # real pairs it fine-tuned on
        "n_test": n_test,
        # a real-data braille stage records its source: its test frames are real DIGIT frames
        "tested_on": "real" if ctx.input("data").metrics.get("source_root") else None,
        **{
            m: _summary([s["test"][m] for s in per_seed])
            for m in ("accuracy", "precision", "recall")
        },
        "test_sim_accuracy": (
            _summary([s["test_sim"]["accuracy"] for s in per_seed])
            if per_seed[0]["test_sim"]
            else None
        ),
        # the same contacts through another unit, seen by no stage before (braille_data)
        "second_unit": unit[0] if unit else None,
        "second_unit_accuracy": (
            _summary([s["second_unit"]["accuracy"] for s in per_seed]) if unit else None
        ),
        "heldout_accuracy": (
            _summary([s["heldout"]["accuracy"] for s in per_seed])
            if per_seed[0]["heldout"]
            else None
        ),
        # the precision its training ran in (None: it only reuses the init stage's models);
        # not "precision", which is the classification score above
        "compute_precision": (
            classifier_precision(ClassifierConfig(**config.classifier.model_dump()), ctx.trainer)
            if ctx.optional_input("init") is None or pool is not None
            else None
        ),
    }


STAGE = StageKind(
    name="classify",
    description="train braille classifiers over seeds (optionally fine-tune on real), test on real",
    config_model=ClassifyConfig,
    run=_run,
    input_slots={"data": True, "images": False, "init": False},
    precision_dependent=True,
    fits=True,
)
