"""Seeds of one classifier trained as one stacked (grouped-convolution) model: each seed's
result is the one training it alone gives."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import pytest
import torch
from lightning.pytorch.callbacks import Callback
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from tactile_bench.classify.model import ResNetClassifier
from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.classify.stacked import SeedBatches, stack_networks, unstack_network
from tactile_bench.classify.train import (
    ClassifierConfig,
    batchable,
    predict,
    train_classifier,
    train_classifiers,
)
from tactile_bench.training import EVERY_KEY, ResumableSampler

CLASSES = 4
SEEDS = (0, 1, 2)
QUIET = {"accelerator": "cpu", "enable_progress_bar": False, "logger": False}
# 40 images in batches of 8: 5 steps an epoch, 10 in all (the last batch of an epoch full)
TINY = dict(width=4, blocks=(1, 1, 1, 1), epochs=2, batch_size=8, precise_bn_images=16)


def data(n: int, seed: int, size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    labels = torch.arange(n) % CLASSES
    return torch.rand(n, 3, size, size, generator=gen) + labels.view(-1, 1, 1, 1) * 0.2, labels


def configs(**overrides: Any) -> list[ClassifierConfig]:
    values = {**TINY, "precision": "32-true", **overrides}
    return [ClassifierConfig(**values, seed=seed) for seed in SEEDS]


def nets(count: int, blocks: tuple[int, ...] = (2, 2, 2, 2)) -> list[nn.Module]:
    """Differently initialised networks, their BatchNorms' weights and statistics random too
    (so that a seed's slice landing in another's place would show)."""
    out = []
    for seed in range(count):
        torch.manual_seed(seed)
        net = ResNetClassifier(num_classes=5, in_channels=3, width=4, blocks=blocks, stem="light")
        for m in net.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.weight.data.uniform_(0.5, 1.5)
                m.bias.data.normal_()
                m.running_mean.normal_()
                m.running_var.uniform_(0.5, 2.0)
        out.append(net)
    return out


def test_stack_then_unstack_gives_every_tensor_back_and_the_same_outputs() -> None:
    separate = nets(3)
    stacked = stack_networks(separate)
    assert stacked.stem[0].groups == 3 and stacked.stem[0].out_channels == 12
    for net, back in zip(separate, unstack_network(stacked, separate[0], 3), strict=True):
        a, b = net.state_dict(), back.state_dict()
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    xs = [torch.randn(6, 3, 32, 32, generator=torch.Generator().manual_seed(k)) for k in range(3)]
    for training in (False, True):  # running statistics, then batch statistics
        stacked.train(training)
        with torch.no_grad():
            together = stacked(torch.cat(xs, dim=1)).view(6, 3, 5)
            for k, net in enumerate(separate):
                alone = net.train(training)(xs[k])
                torch.testing.assert_close(together[:, k], alone, rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    "layer",
    [nn.PReLU(4), nn.GroupNorm(2, 4), nn.Dropout(0.1)],
    ids=["parametrised", "mixes channels", "draws random numbers"],
)
def test_layers_that_cannot_be_stacked_are_refused(layer: nn.Module) -> None:
    nets_with_it = [nn.Sequential(nn.Conv2d(3, 4, 3), layer) for _ in range(2)]
    with pytest.raises(ValueError, match="cannot stack"):
        stack_networks(nets_with_it)


def test_networks_of_different_structures_are_refused() -> None:
    with pytest.raises(ValueError, match="differs in structure"):
        stack_networks([*nets(1, (1, 1)), *nets(1, (1, 2))])


def test_seed_batches_are_each_seeds_dataloader_batches_epoch_after_epoch() -> None:
    x, y = torch.randn(23, 2, 3, 3), torch.arange(23)
    batches = SeedBatches((x, y), [4, 9], batch_size=5)
    loaders = []
    for seed in (4, 9):
        gen = torch.Generator().manual_seed(seed)
        sampler = ResumableSampler(23, gen, 5)
        loaders.append(
            DataLoader(TensorDataset(x, y), batch_size=5, sampler=sampler, generator=gen)
        )
    assert len(batches) == len(loaders[0]) == 5
    for _ in range(3):  # a new permutation each epoch, the last batch short
        for (xs, ys), *alone in zip(batches, *loaders, strict=True):
            for k, (xk, yk) in enumerate(alone):
                assert torch.equal(xs[:, 2 * k : 2 * k + 2], xk) and torch.equal(ys[k], yk)


def _init(seed: int) -> BrailleClassifier:
    """A model to fine-tune from: random weights, BatchNorm weights away from their init."""
    torch.manual_seed(seed)
    model = BrailleClassifier(num_classes=CLASSES, width=4, blocks=TINY["blocks"])
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            m.weight.data.uniform_(0.5, 1.5)
    return model


@pytest.mark.parametrize("fine_tune", [False, True], ids=["from scratch", "from inits"])
def test_batched_seeds_equal_each_seed_trained_alone(tmp_path: Path, fine_tune: bool) -> None:
    fg, labels = data(40, seed=0)
    test_fg, _ = data(24, seed=1)
    inits = [_init(10 + seed) for seed in SEEDS] if fine_tune else None
    batched = train_classifiers(
        fg, labels, configs(), tmp_path / "b", [], QUIET, num_classes=CLASSES, inits=inits
    )
    for k, config in enumerate(configs()):
        alone = train_classifier(
            fg,
            labels,
            config,
            tmp_path / f"a{k}",
            [],
            dict(QUIET),
            num_classes=CLASSES,
            init=inits[k] if inits else None,
        )
        a, b = alone.state_dict(), batched[k].state_dict()
        assert a.keys() == b.keys() and not batched[k].training
        # Grouped convolutions sum in another order than one seed's convolution, so weights
        # differ in the last bits (measured at most 5e-6 after these 10 steps). Adam divides
        # each gradient by its own running magnitude, so a gradient that is mostly rounding
        # noise still moves its weight by a fraction of lr = 1e-3: atol lr / 10 allows that
        # and still catches a wrong batch or a mixed-up seed (each moves weights ~lr a step).
        # Images are 32 x 32: at 16 x 16 the last stage runs at 1 x 1 px, where some BatchNorm
        # biases get a gradient that is exactly zero but for rounding (all that follows them
        # is renormalised over the batch), whose sign alone sets their Adam steps (+-lr), in
        # train_classifier itself too: there it moves them 2.5e-4 from 1 thread to 2.
        for key in a:
            torch.testing.assert_close(b[key], a[key], rtol=1e-4, atol=1e-4, msg=key)
        assert torch.equal(predict(batched[k], test_fg), predict(alone, test_fg))


def test_each_seed_trains_on_its_own_rows_as_on_its_own_tensor(tmp_path: Path) -> None:
    """A classify stage holds out other images for each seed: seed k's rows of the one
    tensor train as ``train_classifier`` trains on ``fg[rows_k]``."""
    fg, labels = data(48, seed=0)
    test_fg, _ = data(24, seed=1)
    rows = [torch.randperm(48, generator=torch.Generator().manual_seed(s))[:40] for s in SEEDS]
    batched = train_classifiers(
        fg, labels, configs(), tmp_path / "b", [], QUIET, num_classes=CLASSES, subsets=rows
    )
    for k, config in enumerate(configs()):
        own = rows[k]
        alone = train_classifier(
            fg[own], labels[own], config, tmp_path / f"a{k}", [], dict(QUIET), num_classes=CLASSES
        )
        a, b = alone.state_dict(), batched[k].state_dict()
        for key in a:  # the tolerance of the test above, for the same reasons
            torch.testing.assert_close(b[key], a[key], rtol=1e-4, atol=1e-4, msg=key)
        assert torch.equal(predict(batched[k], test_fg), predict(alone, test_fg))


def test_models_of_one_seed_on_different_data_shift_as_each_alone(tmp_path: Path) -> None:
    """The diagnosis trains one seed's classifier on several sets (sim, sim + effects, real)
    with random shifts: batched, each member draws the shifts that training it alone draws."""
    sets = [data(40, seed=s)[0] for s in (0, 5, 9)]
    _, labels = data(40, seed=0)
    config = ClassifierConfig(**TINY, precision="32-true", seed=3, augment=True, shift_px=3)
    assert batchable([config] * 3, QUIET) is None
    rows = [torch.arange(40) + 40 * k for k in range(3)]
    batched = train_classifiers(
        torch.cat(sets), labels.repeat(3), [config] * 3, tmp_path / "b", [], QUIET,
        num_classes=CLASSES, subsets=rows,
    )  # fmt: skip
    test_fg, _ = data(24, seed=1)
    for k, fg in enumerate(sets):
        alone = train_classifier(
            fg, labels, config, tmp_path / f"a{k}", [], dict(QUIET), num_classes=CLASSES
        )
        a, b = alone.state_dict(), batched[k].state_dict()
        for key in a:  # the tolerance of the tests above, for the same reasons
            torch.testing.assert_close(b[key], a[key], rtol=1e-4, atol=1e-4, msg=key)
        assert torch.equal(predict(batched[k], test_fg), predict(alone, test_fg))
    unshifted = train_classifier(
        sets[0], labels, dataclasses.replace(config, augment=False), tmp_path / "n", [],
        dict(QUIET), num_classes=CLASSES,
    )  # fmt: skip
    moved = max(
        float((unshifted.state_dict()[k] - batched[0].state_dict()[k]).abs().max())
        for k in unshifted.state_dict()
        if unshifted.state_dict()[k].is_floating_point()
    )
    assert moved > 1e-3  # the shifts did reach the batched training


class Killed(Exception):
    """Stands in for SIGKILL: training stops dead, nothing more is saved."""


class KillAt(Callback):
    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_end(self, trainer: Any, *args: Any) -> None:
        if trainer.global_step >= self.step:
            raise Killed


def test_a_killed_batched_fit_resumes_where_it_stopped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    fg, labels = data(40, seed=0)
    kw = {**QUIET, EVERY_KEY: 3}

    def train(out: str, extra: dict[str, Any] | None = None) -> list[BrailleClassifier]:
        settings = {**kw, **(extra or {})}
        return train_classifiers(fg, labels, configs(), tmp_path / out, [], settings, CLASSES)

    straight = train("a")
    with pytest.raises(Killed):
        train("b", {"callbacks": [KillAt(7)]})  # 5 steps an epoch: killed in epoch 2
    assert torch.load(tmp_path / "b/checkpoints/last.ckpt", weights_only=True)["global_step"] == 6
    with caplog.at_level(logging.INFO, logger="tactile_bench"):
        resumed = train("b")
    assert "resuming from" in caplog.text  # mid-epoch 2: each seed's sampler one batch in
    for a, b in zip(straight, resumed, strict=True):
        sa, sb = a.state_dict(), b.state_dict()
        assert all(torch.equal(sa[k], sb[k]) for k in sa)  # the same kernels: bit for bit


def test_batchable_says_why_not() -> None:
    assert batchable(configs(), QUIET) is None
    assert "augment" in str(batchable(configs(augment=True), QUIET))  # seeds differ
    assert "val_fraction" in str(batchable(configs(val_fraction=0.2), QUIET))
    assert "seed" in str(batchable([*configs(), ClassifierConfig(**TINY, lr=0.1)], QUIET))
    assert "processes" in str(batchable(configs(), {"strategy": "ddp", "devices": 2}))
    fg, labels = data(8, seed=0)
    with pytest.raises(ValueError, match="augment"):
        train_classifiers(fg, labels, configs(augment=True), "unused", [], QUIET)
