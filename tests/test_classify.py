"""Classifier: architecture, training loop learns, metrics are right, runs are reproducible."""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from tactile_bench.classify.model import ResNetClassifier, count_flops
from tactile_bench.classify.module import BrailleClassifier, random_shift
from tactile_bench.classify.train import (
    ClassifierConfig,
    _ResumableDataModule,
    evaluate,
    predict,
    train_classifier,
)
from tactile_bench.data.datamodule import ForegroundDataModule, stratified_split
from tactile_bench.pipeline.loggers import finish_loggers, make_loggers
from tactile_bench.training import DeviceBatches, ResumableSampler

N_CLASSES = 9
SIZE = 32
FAST = {"enable_progress_bar": False}
TINY = dict(width=8, blocks=(1, 1), lr=1e-2, batch_size=20)


COLOURS = torch.tensor(
    [
        [1, 0, 0],
        [0, 1, 0],
        [0, 0, 1],
        [-1, 0, 0],
        [0, -1, 0],
        [0, 0, -1],
        [1, 1, 0],
        [0, 1, 1],
        [1, 0, 1],
    ],
    dtype=torch.float32,
)


def blobs(n_per_class: int, seed: int, size: int = SIZE) -> tuple[torch.Tensor, torch.Tensor]:
    """Trivially separable foregrounds: class c = a blob of colour c at grid position c,
    on noise around 0.5, jittered by a pixel or so."""
    g = torch.Generator().manual_seed(seed)
    labels = torch.arange(N_CLASSES).repeat_interleave(n_per_class)
    n = len(labels)
    cy = (labels // 3).float() * size / 3 + size / 6 + torch.randn(n, generator=g)
    cx = (labels % 3).float() * size / 3 + size / 6 + torch.randn(n, generator=g)
    ys, xs = torch.meshgrid(torch.arange(size).float(), torch.arange(size).float(), indexing="ij")
    blob = torch.exp(-((ys - cy[:, None, None]) ** 2 + (xs - cx[:, None, None]) ** 2) / 18.0)
    fg = 0.5 + 0.3 * blob[:, None] * COLOURS[labels][:, :, None, None]
    fg = fg + 0.02 * torch.randn(fg.shape, generator=g)
    return fg, labels


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[BrailleClassifier, Path]:
    out = tmp_path_factory.mktemp("clf")
    fg, labels = blobs(30, seed=0)
    config = ClassifierConfig(**TINY, epochs=4, seed=0)
    model = train_classifier(fg, labels, config, out, trainer_kwargs=FAST, num_classes=N_CLASSES)
    return model, out


def test_output_shape_64() -> None:
    model = ResNetClassifier(width=8).eval()
    assert model(torch.zeros(2, 3, 64, 64)).shape == (2, 27)
    depth_model = ResNetClassifier(in_channels=1, num_classes=5, width=4, blocks=(1, 1))
    assert depth_model(torch.zeros(3, 1, 64, 64)).shape == (3, 5)


@pytest.mark.parametrize("stem", ["cifar", "light", "imagenet"])
def test_stems(stem: str) -> None:
    model = ResNetClassifier(width=4, stem=stem).eval()
    assert model(torch.zeros(1, 3, 64, 64)).shape == (1, 27)


def test_params_and_flops_scale_with_width() -> None:
    def n_params(m: torch.nn.Module) -> int:
        return sum(p.numel() for p in m.parameters())

    small, big = ResNetClassifier(width=8), ResNetClassifier(width=16)
    # Convolutions dominate: doubling the width about quadruples parameters and FLOPs.
    assert 3.5 < n_params(big) / n_params(small) < 4.1
    assert 3.5 < count_flops(big) / count_flops(small) < 4.1
    assert n_params(ResNetClassifier(width=64)) == pytest.approx(11.18e6, rel=0.01)


def test_random_shift_moves_content() -> None:
    x = torch.zeros(4, 1, 8, 8)
    x[:, :, 4, 4] = 1.0
    out = random_shift(x, 2, torch.Generator().manual_seed(0))
    assert out.shape == x.shape
    assert torch.equal(out.sum(dim=(1, 2, 3)), x.sum(dim=(1, 2, 3)))
    assert random_shift(x, 0) is x


def test_datamodule_split_is_stratified_and_seeded() -> None:
    fg, labels = blobs(10, seed=1)
    keep, held = stratified_split(labels, 0.2, seed=3)
    assert len(held) == 2 * N_CLASSES
    assert torch.equal(torch.bincount(labels[held]), torch.full((N_CLASSES,), 2))
    assert set(keep.tolist()).isdisjoint(held.tolist())
    assert torch.equal(held, stratified_split(labels, 0.2, seed=3)[1])
    dm = ForegroundDataModule((fg, labels), val_fraction=0.2, batch_size=7, seed=5)
    assert len(dm.train_set) == 72 and dm.val_set is not None and len(dm.val_set) == 18
    first = [next(iter(dm.train_dataloader()))[1] for _ in range(2)]
    assert torch.equal(first[0], first[1])  # same seed, same batch order
    assert dm.test_dataloader() == []


def test_training_learns_separable_data(trained: tuple[BrailleClassifier, Path]) -> None:
    model, out = trained
    fg, labels = blobs(10, seed=123)  # fresh samples
    result = evaluate(model, fg, labels, num_classes=N_CLASSES)
    assert result["accuracy"] > 0.9, result
    assert (out / "checkpoints" / "last.ckpt").is_file()
    assert not model.training


def test_evaluate_matches_manual_computation(trained: tuple[BrailleClassifier, Path]) -> None:
    model, _ = trained
    fg, labels = blobs(6, seed=7)
    fg = fg + 0.15 * torch.randn(fg.shape, generator=torch.Generator().manual_seed(1))
    result = evaluate(model, fg, labels, batch_size=16, num_classes=N_CLASSES)
    with torch.no_grad():
        preds = model(fg).argmax(1)
    assert torch.equal(preds, predict(model, fg, batch_size=5))
    assert result["n"] == len(labels)
    assert result["accuracy"] == pytest.approx((preds == labels).float().mean().item())
    confusion = torch.tensor(result["confusion"])
    assert confusion.shape == (N_CLASSES, N_CLASSES)
    assert int(confusion.sum()) == len(labels)
    assert torch.equal(confusion.sum(1), torch.bincount(labels, minlength=N_CLASSES))
    recalls, precisions = [], []
    for c in range(N_CLASSES):
        tp = int(((preds == c) & (labels == c)).sum())
        recalls.append(tp / int((labels == c).sum()))
        n_pred = int((preds == c).sum())
        precisions.append(tp / n_pred if n_pred else 0.0)
    assert result["per_class_accuracy"] == pytest.approx(recalls)
    assert result["recall"] == pytest.approx(sum(recalls) / N_CLASSES)
    assert result["precision"] == pytest.approx(sum(precisions) / N_CLASSES)
    for key in ("accuracy", "precision", "recall"):
        assert isinstance(result[key], float)


def test_evaluate_absent_class_is_none(trained: tuple[BrailleClassifier, Path]) -> None:
    model, _ = trained
    fg, labels = blobs(4, seed=9)
    mask = labels != 0
    result = evaluate(model, fg[mask], labels[mask], num_classes=N_CLASSES)
    assert result["per_class_accuracy"][0] is None
    assert result["n"] == int(mask.sum())


def test_same_seed_same_result(tmp_path: Path) -> None:
    fg, labels = blobs(8, seed=2)
    test_fg, test_labels = blobs(4, seed=3)
    config = ClassifierConfig(**TINY, epochs=1, seed=11, augment=True)
    results, weights = [], []
    for run in range(2):
        model = train_classifier(
            fg, labels, config, tmp_path / f"r{run}", trainer_kwargs=FAST, num_classes=N_CLASSES
        )
        results.append(evaluate(model, test_fg, test_labels, num_classes=N_CLASSES))
        weights.append(model.net.fc.weight.detach().clone())
    assert results[0] == results[1]
    assert torch.equal(weights[0], weights[1])


def _loader_and_device_batches(
    x: torch.Tensor, y: torch.Tensor, batch_size: int
) -> tuple[DataLoader, DeviceBatches]:
    """The CPU path's DataLoader and DeviceBatches, each with its own same-seeded sampler."""
    samplers = []
    for _ in range(2):
        gen = torch.Generator().manual_seed(5)
        samplers.append((ResumableSampler(len(x), gen, batch_size), gen))
    (s1, g1), (s2, g2) = samplers
    loader = DataLoader(TensorDataset(x, y), batch_size=batch_size, sampler=s1, generator=g1)
    return loader, DeviceBatches((x, y), s2, batch_size, g2)


def test_device_batches_are_the_dataloaders_batches_epoch_after_epoch_and_resumed() -> None:
    x, y = torch.randn(23, 3, 4, 4), torch.arange(23)
    loader, resident = _loader_and_device_batches(x, y, batch_size=5)
    assert len(resident) == len(loader) == 5
    for _ in range(3):  # each epoch a new permutation, drawn after the loader's base seed
        for (a, b), (c, d) in zip(loader, resident, strict=True):
            assert torch.equal(a, c) and torch.equal(b, d)
    epoch, skip = loader.sampler.next_epoch_state(), 2
    for sampler in (loader.sampler, resident.sampler):
        sampler.resume(epoch, skip)  # a checkpoint's position: the next epoch's third batch
    resumed = [[b for _, b in batches] for batches in (loader, resident)]
    assert len(resumed[0]) == 3 and all(map(torch.equal, *resumed))


def test_resident_training_on_the_cpu_is_bit_identical_to_the_dataloaders(
    tmp_path: Path,
) -> None:
    """The accelerator's path (images on the device, batches indexed there) run on the CPU:
    the same weights as the DataLoader's, bit for bit (23 images: a short last batch)."""
    fg, labels = blobs(3, seed=4)
    fg, labels = fg[:23], labels[:23]
    config = ClassifierConfig(**{**TINY, "batch_size": 5}, epochs=2, seed=3, augment=True)
    weights = []
    for resident in (False, True):
        model = train_classifier(
            fg,
            labels,
            config,
            tmp_path / str(resident),
            trainer_kwargs=FAST,
            num_classes=N_CLASSES,
            resident=resident,
        )
        weights.append(model.state_dict())
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])


def test_on_an_accelerator_the_training_images_move_there_once() -> None:
    """The path is chosen by the device the attached Trainer fits on (here ``meta``)."""
    fg, labels = blobs(2, seed=5)
    data = _ResumableDataModule(train=(fg, labels), batch_size=4)
    assert isinstance(data.train_dataloader(), DataLoader)  # no Trainer: the CPU
    data.trainer = SimpleNamespace(strategy=SimpleNamespace(root_device=torch.device("meta")))
    first, again = data.train_dataloader(), data.train_dataloader()
    assert isinstance(first, DeviceBatches)
    assert all(t.device.type == "meta" for t in first.tensors)
    assert all(a is b for a, b in zip(first.tensors, again.tensors, strict=True))  # once
    x, y = next(iter(first))
    assert x.device.type == "meta" and x.shape == (4, *fg.shape[1:]) and y.shape == (4,)


def test_lightning_test_metrics(trained: tuple[BrailleClassifier, Path]) -> None:
    import lightning as L

    model, _ = trained
    fg, labels = blobs(5, seed=4)
    dm = ForegroundDataModule((fg, labels), test=(fg, labels), batch_size=8)
    trainer = L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False)
    (logged,) = trainer.test(model, datamodule=dm, verbose=False)
    ours = evaluate(model, fg, labels, num_classes=N_CLASSES)
    assert logged["test_acc"] == pytest.approx(ours["accuracy"], abs=1e-6)
    assert logged["test_precision"] == pytest.approx(ours["precision"], abs=1e-6)
    assert model.test_confusion is not None
    assert model.test_confusion.tolist() == ours["confusion"]


def _csv_columns(path: Path) -> list[str]:
    with path.open() as f:
        return next(csv.reader(f))


def test_loggers_csv_only_when_disabled(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_BENCH_NO_WANDB", "1")
    loggers = make_loggers(tmp_path, "run")
    assert [type(lg).__name__ for lg in loggers] == ["CSVLogger"]
    assert [type(lg).__name__ for lg in make_loggers(tmp_path, "x", wandb=False)] == ["CSVLogger"]


def test_training_writes_csv_and_offline_wandb(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("wandb")
    monkeypatch.delenv("TACTILE_BENCH_NO_WANDB", raising=False)
    monkeypatch.delenv("WANDB_MODE", raising=False)
    monkeypatch.setenv("WANDB_BASE_URL", "http://127.0.0.1:9")  # would fail if it went online
    monkeypatch.setenv("WANDB_API_KEY", "")
    for var in ("WANDB_DIR", "WANDB_SILENT", "WANDB_CONSOLE"):
        monkeypatch.delenv(var, raising=False)
    loggers = make_loggers(tmp_path / "logs", "tiny")
    assert [type(lg).__name__ for lg in loggers] == ["CSVLogger", "WandbLogger"]
    fg, labels = blobs(4, seed=5)
    config = ClassifierConfig(**TINY, epochs=1)
    train_classifier(
        fg,
        labels,
        config,
        tmp_path / "out",
        loggers=loggers,
        trainer_kwargs={**FAST, "log_every_n_steps": 1},
        num_classes=N_CLASSES,
    )
    finish_loggers(loggers)
    metrics = list((tmp_path / "logs" / "tiny").glob("version_*/metrics.csv"))
    assert len(metrics) == 1
    assert {"train_loss_step", "train_acc", "epoch"} <= set(_csv_columns(metrics[0]))
    runs = list((tmp_path / "logs" / "wandb").glob("offline-run-*"))
    assert len(runs) == 1
    assert list(runs[0].glob("run-*.wandb"))


def test_precision_defaults_to_auto_and_rejects_unknown_values() -> None:
    assert ClassifierConfig().precision == "auto"
    assert ClassifierConfig(precision="bf16-mixed").precision == "bf16-mixed"
    with pytest.raises(ValueError, match="precision must be one of auto, 32-true, bf16-mixed"):
        ClassifierConfig(precision="bf16")


@pytest.mark.parametrize("native", [False, True])
def test_training_runs_in_the_precision_auto_resolves_to(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, native: bool
) -> None:
    from lightning.pytorch.callbacks import Callback

    from tactile_bench import hardware
    from tactile_bench.classify.train import classifier_precision

    class Seen(Callback):
        def __init__(self) -> None:
            self.precision: list[str] = []

        def on_train_start(self, trainer: object, pl_module: object) -> None:
            self.precision.append(trainer.precision)  # type: ignore[attr-defined]

    monkeypatch.setattr(hardware, "native_bf16", lambda device="cpu": native)
    expected = "bf16-mixed" if native else "32-true"
    config = ClassifierConfig(width=4, blocks=(1,), batch_size=9, epochs=1, precise_bn_images=0)
    assert classifier_precision(config) == expected
    assert classifier_precision(config, {"precision": "32-true"}) == "32-true"
    fg, labels = blobs(1, seed=0, size=16)
    seen = Seen()
    kwargs = {**FAST, "callbacks": [seen], "enable_checkpointing": False}
    train_classifier(fg, labels, config, tmp_path, [], kwargs, num_classes=N_CLASSES)
    assert seen.precision == [expected]
