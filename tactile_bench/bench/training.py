"""Training throughput of every trainable translator and of the braille classifier.

Each model trains a few steps under a plain Lightning Trainer in four variants: fp32 or
bf16 autocast (``precision="bf16-mixed"``; a translator's config ``precision`` is set to
the same), each with NCHW or channels_last weights (the module is converted once;
convolutions then keep activations channels_last). Both precisions are measured whatever
``precision: auto`` picks here, so the table shows what bf16 costs or gains on this CPU.
A callback times each optimiser step (forward, backward, update); the first steps are
warm-up and not counted, the rest give a median (a bf16 variant on a CPU that emulates
bf16 times ``EMULATED_BF16_STEPS`` steps after one warm-up: enough for its rate, and the
full count would take an hour). Data are real braille foregrounds of the simulated
fine-tuning set.

The seeds row trains a classify stage's seeds one after another and as one batched model
(``classify.train_classifiers``), with table1's and quick's classifier settings.

The cost-versus-work check trains ONE epoch at 1x, 2x and 4x the data through the same
entry points a recipe uses (``Translator.fit_pairs``, ``classify.train_classifier``) and
times the epoch itself (Trainer set-up excluded, reported apart).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback
from torch.utils.data import DataLoader, TensorDataset

from tactile_bench.bench.timing import peak_memory
from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.classify.train import ClassifierConfig, train_classifier, train_classifiers
from tactile_bench.hardware import native_bf16
from tactile_bench.translators import Translator, discover

#: timed steps of a bf16 variant on a CPU that emulates bf16 (20-100x slower than fp32)
EMULATED_BF16_STEPS = 2

VARIANTS: dict[str, tuple[bool, bool]] = {  # name -> (bf16, channels_last)
    "fp32": (False, False),
    "bf16": (True, False),
    "fp32+channels_last": (False, True),
    "bf16+channels_last": (True, True),
}


class StepTimer(Callback):
    """Wall and CPU seconds of every training batch (hook start to hook end)."""

    def __init__(self) -> None:
        self.wall: list[float] = []
        self.cpu: list[float] = []
        self.epoch_s: list[float] = []
        self._t = (0.0, 0.0)
        self._epoch = 0.0

    def on_train_batch_start(self, *args: Any, **kwargs: Any) -> None:
        self._t = (time.perf_counter(), time.process_time())

    def on_train_batch_end(self, *args: Any, **kwargs: Any) -> None:
        self.wall.append(time.perf_counter() - self._t[0])
        self.cpu.append(time.process_time() - self._t[1])

    def on_train_epoch_start(self, *args: Any, **kwargs: Any) -> None:
        self._epoch = time.perf_counter()

    def on_train_epoch_end(self, *args: Any, **kwargs: Any) -> None:
        self.epoch_s.append(time.perf_counter() - self._epoch)


def trainable_translators() -> dict[str, type[Translator]]:
    """Every registered translator that has something to fit (plugins included)."""
    out = {}
    for name, entry in discover().items():
        try:
            cls = entry.load()
        except Exception:  # a broken plugin is reported by `list`, not benchmarked
            continue
        if cls.trainable:
            out[name] = cls
    return out


def _trainer(callbacks: list[Callback], root: str, **kw: Any) -> L.Trainer:
    settings: dict[str, Any] = dict(
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_model_summary=False,
        enable_progress_bar=False,
        num_sanity_val_steps=0,
        default_root_dir=root,
        callbacks=callbacks,
    )
    settings.update(kw)
    return L.Trainer(**settings)


def step_throughput(
    make: Callable[[bool], L.LightningModule],
    data: tuple[torch.Tensor, torch.Tensor],
    batch_size: int,
    warmup: int,
    steps: int,
) -> dict[str, Any]:
    """Images/s of training steps of ``make(bf16)`` in every variant of ``VARIANTS``."""
    out = {}
    need = (warmup + steps) * batch_size  # a small data set is cycled to fill the steps
    loader_data = TensorDataset(*(_repeat(x, max(need, len(x))) for x in data))
    for variant, (bf16, channels_last) in VARIANTS.items():
        emulated = bf16 and not native_bf16()
        warm, timed = (1, EMULATED_BF16_STEPS) if emulated else (warmup, steps)
        module = make(bf16)
        if channels_last:
            module = module.to(memory_format=torch.channels_last)
        timer = StepTimer()
        loader = DataLoader(
            loader_data,
            batch_size=batch_size,
            shuffle=True,
            drop_last=True,
            generator=torch.Generator().manual_seed(0),
        )
        with tempfile.TemporaryDirectory(prefix="tb_bench_") as tmp, peak_memory() as mem:
            trainer = _trainer(
                [timer],
                tmp,
                max_epochs=1,
                limit_train_batches=warm + timed,
                precision="bf16-mixed" if bf16 else "32-true",
            )
            trainer.fit(module, loader)
        wall = statistics.median(timer.wall[warm:])
        cpu = statistics.median(timer.cpu[warm:])
        out[variant] = {
            "emulated_bf16": emulated,
            "images_per_s": batch_size / wall,
            "images_per_cpu_s": batch_size / max(cpu, 1e-9),
            "median_step_s": wall,
            "steps": len(timer.wall) - warm,
            "peak_mib": round(mem.delta_mib, 1),
        }
    base = out["fp32"]["images_per_s"]
    for row in out.values():
        row["speedup_vs_fp32"] = row["images_per_s"] / base
    return out


def _translator_maker(
    cls: type[Translator], overrides: dict[str, Any]
) -> Callable[[bool], L.LightningModule]:
    def make(bf16: bool) -> L.LightningModule:
        return cls({**overrides, "precision": "bf16-mixed" if bf16 else "32-true"})

    return make


def training_throughput(
    depth: torch.Tensor,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    warmup: int,
    steps: int,
    progress: bool = True,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Step throughput of each trainable translator (default config unless ``overrides``
    names it: ``{"diffusion": {"preset": "tiny"}}``) and of the classifier."""
    out: dict[str, Any] = {}
    overrides = overrides or {}
    for name, cls in trainable_translators().items():
        settings = overrides.get(name, {})
        batch = cls.Config(**settings).batch_size
        out[f"translator:{name}"] = step_throughput(
            _translator_maker(cls, settings), (depth, foreground), batch, warmup, steps
        )
        if progress:
            _say(f"translator:{name}", batch, out[f"translator:{name}"])
    config = ClassifierConfig()

    def classifier(bf16: bool) -> L.LightningModule:
        torch.manual_seed(config.seed)
        return BrailleClassifier(width=config.width, blocks=config.blocks, stem=config.stem)

    out["classifier"] = step_throughput(
        classifier, (foreground, labels), config.batch_size, warmup, steps
    )
    if progress:
        _say("classifier", config.batch_size, out["classifier"])
    return out


def _say(name: str, batch: int, rows: dict[str, Any]) -> None:
    cells = "  ".join(f"{v}: {r['images_per_s']:.1f}" for v, r in rows.items())
    print(f"  training {name} (batch {batch}) img/s  {cells}", flush=True)


def epoch_scaling(
    depth: torch.Tensor,
    foreground: torch.Tensor,
    labels: torch.Tensor,
    sizes: dict[str, tuple[int, ...]],
    overrides: dict[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """One training epoch at each size (images) for each translator and the classifier."""
    out: dict[str, Any] = {}
    overrides = overrides or {}
    for name, cls in trainable_translators().items():
        rows = {}
        for n in sizes["translator"]:
            translator = cls(overrides.get(name, {}))
            timer = StepTimer()
            with tempfile.TemporaryDirectory(prefix="tb_bench_") as tmp, peak_memory() as mem:
                start = time.perf_counter()
                translator.fit_pairs(
                    _repeat(depth, n),
                    _repeat(foreground, n),
                    Path(tmp),
                    {
                        "max_epochs": 1,
                        "max_steps": -1,
                        "enable_progress_bar": False,
                        "callbacks": [timer],
                    },
                )
                total = time.perf_counter() - start
            rows[n] = _epoch_row(n, timer, total, mem.delta_mib)
        out[f"translator:{name}"] = _with_linearity(rows)
    rows = {}
    for n in sizes["classifier"]:
        timer = StepTimer()
        with tempfile.TemporaryDirectory(prefix="tb_bench_") as tmp, peak_memory() as mem:
            start = time.perf_counter()
            train_classifier(
                _repeat(foreground, n),
                _repeat(labels, n),
                ClassifierConfig(epochs=1),
                out_dir=tmp,
                loggers=[],
                trainer_kwargs={"enable_progress_bar": False, "callbacks": [timer]},
            )
            total = time.perf_counter() - start
        rows[n] = _epoch_row(n, timer, total, mem.delta_mib)
    out["classifier"] = _with_linearity(rows)
    return out


def _repeat(x: torch.Tensor, n: int) -> torch.Tensor:
    """The first ``n`` items of ``x`` cycled (sizes above the data set repeat it)."""
    idx = torch.arange(n) % len(x)
    return x[idx]


def _epoch_row(n: int, timer: StepTimer, total: float, peak: float) -> dict[str, Any]:
    epoch = timer.epoch_s[0] if timer.epoch_s else sum(timer.wall)
    return {
        "images": n,
        "epoch_s": epoch,
        "call_s": total,
        "setup_s": total - epoch,
        "images_per_s": n / epoch,
        "peak_mib": round(peak, 1),
    }


def _with_linearity(rows: dict[int, dict[str, Any]]) -> dict[str, Any]:
    base_n = min(rows)
    base = rows[base_n]["epoch_s"]
    for n, row in rows.items():
        row["linearity"] = row["epoch_s"] / (n / base_n * base)
    return {f"{n // base_n}x": row for n, row in sorted(rows.items())}


#: the classifier settings of the recipes' classify stages, for the seeds row
SEED_SETTINGS: dict[str, dict[str, Any]] = {
    "table1": dict(width=16, blocks=(1, 1, 1, 1), batch_size=64, lr=0.002),
    "quick": dict(width=8, blocks=(1, 1, 1, 1), batch_size=32, lr=0.008),
}


def seed_batching(
    foreground: torch.Tensor, labels: torch.Tensor, images: int, seeds: int = 3, epochs: int = 1
) -> dict[str, Any]:
    """Wall seconds of training ``seeds`` classifiers on ``images`` images (the data cycled),
    one after another (``train_classifier``, as ``batch_seeds: false``) and as one batched
    model (``train_classifiers``, the default), for each recipe's classifier settings."""
    x, y = _repeat(foreground, images), _repeat(labels, images)
    quiet = {"enable_progress_bar": False, "enable_checkpointing": False, "logger": False}
    out: dict[str, Any] = {}
    for name, settings in SEED_SETTINGS.items():
        configs = [ClassifierConfig(**settings, epochs=epochs, seed=s) for s in range(seeds)]
        with tempfile.TemporaryDirectory(prefix="tb_bench_") as tmp:
            start = time.perf_counter()
            for config in configs:
                train_classifier(x, y, config, Path(tmp) / str(config.seed), [], dict(quiet))
            in_turn = time.perf_counter() - start
            start = time.perf_counter()
            train_classifiers(x, y, configs, Path(tmp) / "batched", [], dict(quiet))
            batched = time.perf_counter() - start
        out[name] = {
            "seeds": seeds,
            "images": images,
            "epochs": epochs,
            "in_turn_s": in_turn,
            "batched_s": batched,
            "speedup": in_turn / batched,
        }
    return out
