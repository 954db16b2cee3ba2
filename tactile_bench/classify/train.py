"""Train a braille classifier on in-memory foregrounds, and evaluate it.

CPU defaults: width 16, ResNet-18 blocks (2, 2, 2, 2), stride-2 3 x 3 stem (70 MFLOP a
forward pass, see ``classify.model``), Adam lr 1e-3 (the paper's 1e-4 is too slow for a
few epochs from scratch), batch 20 as the paper. ``ClassifierConfig.paper()`` is the paper's
own ResNet-18 setting, for GPUs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import lightning as L
import torch
from lightning.pytorch.loggers import CSVLogger, Logger
from torch import nn
from torch.utils.data import DataLoader
from torchmetrics.functional.classification import (
    multiclass_accuracy,
    multiclass_confusion_matrix,
    multiclass_precision,
    multiclass_recall,
)

from tactile_bench.classify.model import NUM_CLASSES
from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.classify.stacked import (
    SeedBatches,
    SeedDataModule,
    StackedClassifier,
    stack_networks,
    unstack_network,
)
from tactile_bench.data.datamodule import ForegroundDataModule
from tactile_bench.hardware import PRECISIONS, Precision, compute_device, trainer_precision
from tactile_bench.training import (
    DeviceBatches,
    ResumableSampler,
    fingerprint,
    log_interval,
    processes,
    result_settings,
    resumable_fit,
)


@dataclass
class ClassifierConfig:
    """Architecture and optimisation of one classifier training.

    Defaults are sized for a 2-core CPU: about 10k 64 x 64 images train in a few minutes
    and reach their plateau. ``paper()`` gives the paper's ResNet-18 settings.

    ``precise_bn_images``: after training, BatchNorm running statistics are re-estimated
    on up to this many training images with the final weights ("precise BN", Wu & Johnson
    2021). The running averages otherwise lag behind weights that moved fast in a short
    training, and eval-mode accuracy can then collapse; 0 disables it.

    ``precision``: ``auto`` trains in bf16 autocast only where the CPU has bf16 arithmetic
    (AVX-512-BF16, AMX) and in fp32 elsewhere (emulated bf16 on AVX2 is many times slower);
    see ``tactile_bench.hardware``.
    """

    width: int = 16
    blocks: tuple[int, ...] = (2, 2, 2, 2)
    stem: Literal["cifar", "light", "imagenet"] = "light"
    lr: float = 1e-3
    weight_decay: float = 0.0
    batch_size: int = 20
    epochs: int = 4
    seed: int = 0
    precision: Precision = "auto"
    augment: bool = False
    shift_px: int = 2
    val_fraction: float = 0.0
    num_workers: int = 0
    precise_bn_images: int = 2048
    extra: dict[str, Any] = field(default_factory=dict)  # free-form notes, logged as hparams

    def __post_init__(self) -> None:
        self.blocks = tuple(int(b) for b in self.blocks)
        if self.precision not in PRECISIONS:
            raise ValueError(
                f"precision must be one of {', '.join(PRECISIONS)}; got {self.precision!r}"
            )

    @classmethod
    def paper(cls, **overrides: Any) -> ClassifierConfig:
        """The paper's classifier: ResNet-18 (width 64), Adam lr 1e-4, batch 20."""
        values: dict[str, Any] = dict(width=64, blocks=(2, 2, 2, 2), lr=1e-4, batch_size=20)
        values.update(overrides)
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """Plain-type dict (tuples as lists) for hashing, YAML and logging."""
        d = dataclasses.asdict(self)
        d["blocks"] = list(self.blocks)
        return d


def classifier_precision(
    config: ClassifierConfig, trainer_kwargs: Mapping[str, Any] | None = None
) -> Any:
    """The Lightning precision ``train_classifier`` trains ``config`` in: ``trainer_kwargs``'
    own when they set one, else ``config.precision``, ``auto`` resolved for the device."""
    return trainer_precision(dict(trainer_kwargs or {}), config.precision)


def _close_wandb(loggers: Sequence[Logger]) -> None:
    """Finish the wandb runs of ``loggers``: wandb keeps one run per process, and the next
    training's WandbLogger would otherwise silently attach to this one."""
    for logger in loggers:
        if type(logger).__name__ == "WandbLogger" and getattr(logger, "_experiment", None):
            logger.experiment.finish()
            logger._experiment = None


class _ResumableDataModule(ForegroundDataModule):
    """The same shuffled batches as ForegroundDataModule, from a sampler whose position a
    checkpoint restores (so a killed training resumes on the very next batch).

    ``resident``: the training tensors are moved to the fit's device once and batches are
    drawn there (``DeviceBatches``: the same batches in the same order); None: so on an
    accelerator, through a ``DataLoader`` on the CPU.
    """

    def __init__(self, *args: Any, resident: bool | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.generator = torch.Generator().manual_seed(self.seed)
        self.sampler = ResumableSampler(len(self.train_set), self.generator, self.batch_size)
        self.resident = resident
        self._resident: tuple[torch.Tensor, ...] = ()

    def fit_device(self) -> torch.device:
        """The device the attached Trainer fits on (the CPU when there is none)."""
        trainer = self.trainer
        return trainer.strategy.root_device if trainer is not None else torch.device("cpu")

    def train_dataloader(self) -> DataLoader | DeviceBatches:
        device = self.fit_device()
        resident = device.type != "cpu" if self.resident is None else self.resident
        if resident:
            if not self._resident or self._resident[0].device != device:
                self._resident = tuple(t.to(device) for t in self.train_set.tensors)
            return DeviceBatches(self._resident, self.sampler, self.batch_size, self.generator)
        return DataLoader(
            self.train_set,
            batch_size=self.batch_size,
            sampler=self.sampler,
            num_workers=self.num_workers,
            generator=self.generator,
            persistent_workers=self.num_workers > 0,
        )


def train_classifier(
    train_fg: torch.Tensor,
    train_labels: torch.Tensor,
    config: ClassifierConfig | None = None,
    out_dir: str | Path = "classifier",
    loggers: Sequence[Logger] | None = None,
    trainer_kwargs: dict[str, Any] | None = None,
    val: tuple[torch.Tensor, torch.Tensor] | None = None,
    num_classes: int = NUM_CLASSES,
    close_loggers: bool = True,
    init: BrailleClassifier | None = None,
    resident: bool | None = None,
) -> BrailleClassifier:
    """Fit a :class:`BrailleClassifier` on foregrounds (N, C, S, S) and labels (N,).

    Deterministic under ``config.seed`` (weights, batch order, augmentation) on a fixed
    number of threads. Writes ``out_dir/checkpoints/last.ckpt`` (every
    ``trainer_kwargs["checkpoint_every_n_steps"]`` steps and at the end) and resumes from it
    when it exists, ending where an uninterrupted training would; logs to ``loggers``
    (default: a CSVLogger in ``out_dir``). ``trainer_kwargs`` override the Trainer's
    arguments (e.g. ``limit_train_batches``, ``accelerator``, ``enable_progress_bar``).
    Returns the model after the last epoch, in eval mode, on the CPU. With ``init`` the
    weights start from that model (fine-tuning, e.g. on a fraction of real data).
    ``resident``: the training images live on the fit's device and batches are drawn
    there (None: on an accelerator, not on the CPU); the batches and the result are the same.
    """
    config = config or ClassifierConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    L.seed_everything(config.seed, workers=True, verbose=False)
    datamodule = _ResumableDataModule(
        train=(train_fg, train_labels),
        val=val,
        batch_size=config.batch_size,
        num_workers=config.num_workers,
        seed=config.seed,
        val_fraction=config.val_fraction,
        resident=resident,
    )
    model = _new_model(config, int(train_fg.shape[1]), num_classes, init)
    logger_list = list(loggers) if loggers is not None else [CSVLogger(str(out_dir), name="logs")]
    has_val = datamodule.val_set is not None
    n_train = len(datamodule.train_set)
    kwargs = _trainer_settings(config, n_train, has_val, out_dir, logger_list, trainer_kwargs)
    for logger in logger_list:
        logger.log_hyperparams({"classifier": config.to_dict(), "n_train": len(train_labels)})
    key = fingerprint(
        "classifier",
        config.to_dict(),
        num_classes,
        result_settings(kwargs),
        train_fg,
        train_labels,
        init.state_dict() if init is not None else None,
    )
    try:
        resumable_fit(
            model,
            kwargs,
            out_dir / "checkpoints",
            datamodule.sampler,
            key,
            f"classifier training in {out_dir}",
            datamodule=datamodule,
        )
    finally:
        if close_loggers:
            _close_wandb(logger_list)
    if config.precise_bn_images > 0:
        model.to(compute_device(kwargs.get("accelerator")))
        _precise_batchnorm(model, datamodule.train_set.tensors[0], config)
    return model.cpu().eval()


def batchable(
    configs: Sequence[ClassifierConfig], trainer_kwargs: Mapping[str, Any] | None = None
) -> str | None:
    """Why :func:`train_classifiers` cannot train these seeds as one stacked model, or None
    when it can (otherwise train them one at a time with :func:`train_classifier`)."""
    if not configs:
        return "no configs"
    first = {**configs[0].to_dict(), "seed": None}
    if any({**c.to_dict(), "seed": None} != first for c in configs[1:]):
        return "the configs differ in more than their seed"
    settings = dict(trainer_kwargs or {})
    if configs[0].augment and len({c.seed for c in configs}) > 1:
        return (
            "augment=True draws the shifts from the global RNG, which seeds in a batch share "
            "(models of one seed on different data share them as each alone would draw them)"
        )
    if configs[0].val_fraction > 0:
        return "val_fraction > 0: each seed would hold out its own validation split"
    if processes(settings) > 1:
        return "the trainer runs several processes"
    if settings.get("gradient_clip_val") and settings.get("gradient_clip_algorithm") != "value":
        return "gradient norm clipping would clip the seeds by their joint norm"
    if str(settings.get("precision")) in ("16", "16-mixed"):
        return "fp16 loss scaling would skip every seed's step when one seed's overflows"
    return None


def train_classifiers(
    train_fg: torch.Tensor,
    train_labels: torch.Tensor,
    configs: Sequence[ClassifierConfig],
    out_dir: str | Path = "classifiers",
    loggers: Sequence[Logger] | None = None,
    trainer_kwargs: dict[str, Any] | None = None,
    num_classes: int = NUM_CLASSES,
    inits: Sequence[BrailleClassifier] | None = None,
    close_loggers: bool = True,
    subsets: Sequence[torch.Tensor] | None = None,
) -> list[BrailleClassifier]:
    """:func:`train_classifier` for several seeds at once, as one stacked model
    (``classify.stacked``): one pass over the data trains them all.

    ``configs`` differ only in ``seed``; returns each seed's model, in eval mode on the CPU,
    equal up to float rounding to ``train_classifier(train_fg, train_labels, configs[k],
    init=inits[k])``'s (the same initial weights, batches and Adam steps); with ``subsets``,
    seed k trains on ``train_fg[subsets[k]]`` as that call would (each seed's own split, no
    copy of the images). Checkpoints, resume and loggers as there. Raises ValueError when
    :func:`batchable` gives a reason, or when a layer of the network cannot be stacked:
    train the seeds one at a time then.
    """
    reason = batchable(configs, trainer_kwargs)
    if reason is not None:
        raise ValueError(f"train_classifiers: cannot train the seeds as one model: {reason}")
    starts: list[BrailleClassifier | None] = list(inits) if inits is not None else []
    if inits is not None and len(starts) != len(configs):
        raise ValueError(f"train_classifiers: {len(starts)} inits for {len(configs)} configs")
    starts = starts or [None] * len(configs)
    config, seeds = configs[0], [c.seed for c in configs]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    x, y = ForegroundDataModule(train=(train_fg, train_labels)).train_set.tensors
    models = []
    for c, init in zip(configs, starts, strict=True):
        L.seed_everything(c.seed, workers=True, verbose=False)  # each seed's init, as alone
        models.append(_new_model(c, int(x.shape[1]), num_classes, init))
    data = SeedDataModule(SeedBatches((x, y), seeds, config.batch_size, subsets))
    rows = data.batches.subsets
    net = stack_networks([m.net for m in models])
    shift = config.shift_px if config.augment else 0  # one seed: the draws each alone makes
    module = StackedClassifier(
        net, len(models), num_classes, config.lr, config.weight_decay, shift_px=shift
    )
    logger_list = list(loggers) if loggers is not None else [CSVLogger(str(out_dir), name="logs")]
    n_train = rows.shape[1]
    kwargs = _trainer_settings(config, n_train, False, out_dir, logger_list, trainer_kwargs)
    for logger in logger_list:
        logger.log_hyperparams(
            {"classifier": {**config.to_dict(), "seed": seeds}, "n_train": n_train}
        )
    key = fingerprint(
        "classifiers",
        [c.to_dict() for c in configs],
        num_classes,
        result_settings(kwargs),
        train_fg,
        train_labels,
        rows,
        [init.state_dict() if init is not None else None for init in starts],
    )
    try:
        resumable_fit(
            module,
            kwargs,
            out_dir / "checkpoints",
            data.batches.sampler,
            key,
            f"classifier training of seeds {seeds} in {out_dir}",
            datamodule=data,
        )
    finally:
        if close_loggers:
            _close_wandb(logger_list)
    return _unstacked(module, models, configs, x, rows.cpu(), kwargs.get("accelerator"))


def _unstacked(
    module: StackedClassifier,
    models: list[BrailleClassifier],
    configs: Sequence[ClassifierConfig],
    x: torch.Tensor,
    rows: torch.Tensor,
    accelerator: Any,
) -> list[BrailleClassifier]:
    """Each seed's trained weights back in its own model, BatchNorm re-estimated on its own
    training rows as :func:`train_classifier` does; eval mode, on the CPU."""
    nets = unstack_network(module.net.cpu(), models[0].net, len(models))
    for model, trained, config, own in zip(models, nets, configs, rows, strict=True):
        model.net.load_state_dict(trained.state_dict())
        if config.precise_bn_images > 0:
            model.to(compute_device(accelerator))
            _precise_batchnorm(model, x[own], config)
        model.cpu().eval()
    return models


def _new_model(
    config: ClassifierConfig, in_channels: int, num_classes: int, init: BrailleClassifier | None
) -> BrailleClassifier:
    """The network ``config`` describes; with ``init``, its weights start from that model's."""
    model = BrailleClassifier(
        num_classes=num_classes,
        in_channels=in_channels,
        width=config.width,
        blocks=config.blocks,
        stem=config.stem,
        lr=config.lr,
        weight_decay=config.weight_decay,
        augment=config.augment,
        shift_px=config.shift_px,
    )
    if init is not None:
        model.load_state_dict(init.state_dict())
    return model


def _trainer_settings(
    config: ClassifierConfig,
    n_train: int,
    has_val: bool,
    out_dir: Path,
    logger_list: list[Logger],
    trainer_kwargs: dict[str, Any] | None,
) -> dict[str, Any]:
    """The Trainer's arguments for ``n_train`` training images: one device (Lightning's
    ``auto``: the GPU when there is one) and the config's epochs, the caller's overrides on
    top."""
    kwargs: dict[str, Any] = dict(
        max_epochs=config.epochs,
        accelerator="auto",
        devices=1,
        logger=logger_list,
        default_root_dir=str(out_dir),
        enable_model_summary=False,
        enable_progress_bar=True,
        num_sanity_val_steps=0,
        limit_val_batches=1.0 if has_val else 0,
    )
    kwargs.update(trainer_kwargs or {})  # enable_checkpointing=False: no checkpoints/last.ckpt
    kwargs.setdefault("log_every_n_steps", log_interval(n_train, config.batch_size, kwargs, 50))
    kwargs["precision"] = classifier_precision(config, kwargs)
    return kwargs


def _precise_batchnorm(model: BrailleClassifier, x: torch.Tensor, config: ClassifierConfig) -> None:
    """BatchNorm statistics recomputed on a seeded sample of the training images."""
    g = torch.Generator().manual_seed(config.seed)
    idx = torch.randperm(len(x), generator=g)[: config.precise_bn_images]
    recalibrate_batchnorm(model, x[idx], batch_size=max(config.batch_size, 64))


@torch.no_grad()
def recalibrate_batchnorm(model: nn.Module, fg: torch.Tensor, batch_size: int = 64) -> None:
    """Replace BatchNorm running statistics by their exact average over ``fg`` batches."""
    norms = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    if not norms or len(fg) == 0:
        return
    was_training = model.training
    momenta = [m.momentum for m in norms]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative moving average: the plain mean over batches
    model.train()
    batch_size = min(batch_size, len(fg))
    device = next(model.parameters()).device
    for i in range(0, len(fg) - batch_size + 1, batch_size):  # full batches only
        model(fg[i : i + batch_size].to(device).float())
    for m, momentum in zip(norms, momenta, strict=True):
        m.momentum = momentum
    model.train(was_training)


@torch.no_grad()
def predict(model: nn.Module, fg: torch.Tensor, batch_size: int = 256) -> torch.Tensor:
    """Predicted class (N,) for foregrounds (N, C, S, S), in eval mode and in batches."""
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    preds = [
        model(fg[i : i + batch_size].to(device).float()).argmax(dim=1).cpu()
        for i in range(0, len(fg), batch_size)
    ]
    model.train(was_training)
    return torch.cat(preds) if preds else torch.empty(0, dtype=torch.long)


def evaluate(
    model: nn.Module,
    fg: torch.Tensor,
    labels: torch.Tensor,
    batch_size: int = 256,
    num_classes: int = NUM_CLASSES,
) -> dict[str, Any]:
    """The paper's metrics on (fg, labels): micro accuracy, macro precision and recall.

    Returns ``accuracy``, ``precision``, ``recall`` (floats in [0, 1]), ``confusion``
    (``num_classes`` lists of ints, rows = true class, columns = predicted),
    ``per_class_accuracy`` (recall of each class; None for a class absent from ``labels``)
    and ``n``. Macro averages skip classes absent from both labels and predictions (as
    torchmetrics and scikit-learn do); a class never predicted counts as precision 0.
    """
    labels = labels.long().cpu()
    if len(labels) == 0:
        raise ValueError("evaluate: empty test set")
    preds = predict(model, fg, batch_size)
    kw: dict[str, Any] = dict(num_classes=num_classes)
    confusion = multiclass_confusion_matrix(preds, labels, **kw)
    support = confusion.sum(dim=1)
    per_class = [
        float(confusion[c, c] / support[c]) if support[c] > 0 else None for c in range(num_classes)
    ]
    return {
        "accuracy": float(multiclass_accuracy(preds, labels, average="micro", **kw)),
        "precision": float(multiclass_precision(preds, labels, average="macro", **kw)),
        "recall": float(multiclass_recall(preds, labels, average="macro", **kw)),
        "confusion": confusion.tolist(),
        "per_class_accuracy": per_class,
        "n": int(len(labels)),
    }
