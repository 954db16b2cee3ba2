"""A killed or interrupted training resumes from its checkpoint and ends exactly where an
uninterrupted one would (same weights, bit for bit, on the same machine and thread count, on
the CPU; on a GPU to float tolerance, see ``_same``)."""

from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import torch
from lightning.pytorch.callbacks import Callback
from torch.utils.data import DataLoader, TensorDataset

from tactile_bench.classify.train import ClassifierConfig, train_classifier
from tactile_bench.testing import tiny_pairs
from tactile_bench.training import EVERY_KEY, ResumableSampler
from tactile_bench.translators import create_translator

QUIET = {"enable_progress_bar": False}
CGAN = {"max_steps": 12, "batch_size": 6, "generator_channels": 4, "discriminator_channels": 4}


class Killed(Exception):
    """Stands in for SIGKILL inside one process: training stops dead, nothing more is saved."""


class KillAt(Callback):
    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_end(self, trainer: Any, *args: Any) -> None:
        if trainer.global_step >= self.step:
            raise Killed


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    """Bit for bit where the fits ran on the CPU. Where a GPU is there the fits ran on it,
    and cuDNN's convolution kernels may sum in another order from run to run, so the resumed
    weights agree to float tolerance there (bit identity would need deterministic kernels)."""
    assert a.keys() == b.keys()
    for key in a:
        if torch.cuda.is_available():
            torch.testing.assert_close(a[key], b[key], rtol=1e-3, atol=1e-4, msg=key)
        else:
            assert torch.equal(a[key], b[key]), key


def test_sampler_keeps_the_shuffle_of_a_plain_dataloader() -> None:
    """Same batches as DataLoader(shuffle=True, generator=g): results of earlier runs stand."""
    data = TensorDataset(torch.arange(23))
    plain = DataLoader(data, batch_size=5, shuffle=True, generator=torch.Generator().manual_seed(3))
    g = torch.Generator().manual_seed(3)
    ours = DataLoader(data, batch_size=5, sampler=ResumableSampler(23, g, 5), generator=g)
    for _ in range(3):  # Lightning reads len(loader) batches an epoch, then makes a new iterator
        a, b = iter(plain), iter(ours)
        for _ in range(len(plain)):
            assert torch.equal(next(a)[0], next(b)[0])


def test_sampler_resumes_mid_epoch() -> None:
    g = torch.Generator().manual_seed(0)
    sampler = ResumableSampler(10, g, batch_size=2)
    list(sampler)  # epoch 0
    order = list(sampler)  # epoch 1
    sampler.resume(sampler.epoch_state, batches_done=2)
    assert list(sampler) == order[4:]


@pytest.mark.parametrize(
    ("name", "config", "every", "kill", "extra"),
    [
        # manual optimisation (2 steps a batch), dropout: a checkpoint mid-epoch
        ("cgan", CGAN, 2, 10, {}),
        ("colour_match", {"max_steps": 14, "batch_size": 6}, 3, 7, {}),  # at an epoch's end
        # gradient accumulation: never saved between the batches of one step
        ("colour_match", {"max_steps": 8, "batch_size": 4}, 3, 4, {"accumulate_grad_batches": 2}),
    ],
    ids=["cgan", "colour_match", "accumulating"],
)
def test_killed_fit_resumes_to_the_same_weights(
    tmp_path: Path, name: str, config: dict[str, Any], every: int, kill: int, extra: dict
) -> None:
    depth, foreground = tiny_pairs(n=20, size=32)
    settings = {**QUIET, EVERY_KEY: every, **extra}
    straight = create_translator(name, config)
    straight.fit_pairs(depth, foreground, tmp_path / "a", settings)

    with pytest.raises(Killed):
        create_translator(name, config).fit_pairs(
            depth, foreground, tmp_path / "b", {**settings, "callbacks": [KillAt(kill)]}
        )
    ckpt = torch.load(tmp_path / "b/checkpoints/last.ckpt", weights_only=True)
    assert 0 < ckpt["global_step"] <= kill

    resumed = create_translator(name, config)
    report = resumed.fit_pairs(depth, foreground, tmp_path / "b", settings)
    assert report is not None and report.resumed_from_step == ckpt["global_step"]
    _same(straight.state_dict(), resumed.state_dict())


def test_killed_classifier_training_resumes(tmp_path: Path) -> None:
    gen = torch.Generator().manual_seed(0)
    labels = torch.arange(40) % 4
    fg = torch.rand(40, 3, 16, 16, generator=gen) + labels.view(-1, 1, 1, 1) * 0.2
    config = ClassifierConfig(width=4, epochs=2, batch_size=8, precise_bn_images=16)
    kw = {**QUIET, "logger": False, EVERY_KEY: 3}

    def train(out: str, extra: dict[str, Any] | None = None) -> Any:
        return train_classifier(
            fg, labels, config, tmp_path / out, [], {**kw, **(extra or {})}, num_classes=4
        )

    straight = train("a")
    with pytest.raises(Killed):
        train("b", {"callbacks": [KillAt(7)]})  # 5 steps an epoch: killed in epoch 2
    assert torch.load(tmp_path / "b/checkpoints/last.ckpt", weights_only=True)["global_step"] == 6
    _same(straight.state_dict(), train("b").state_dict())


def test_unusable_checkpoints_are_not_resumed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A truncated checkpoint, or one of another fit, is set aside and the fit starts over."""
    depth, foreground = tiny_pairs(n=12, size=32)
    settings = {**QUIET, EVERY_KEY: 2}
    straight = create_translator("cgan", CGAN)
    straight.fit_pairs(depth, foreground, tmp_path / "a", settings)

    ckpt = tmp_path / "b/checkpoints/last.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"PK\x03\x04 cut short")
    fresh = create_translator("cgan", CGAN)
    assert fresh.fit_pairs(depth, foreground, tmp_path / "b", settings).resumed_from_step is None
    assert "unreadable" in caplog.text
    _same(straight.state_dict(), fresh.state_dict())

    other = {**CGAN, "lr": 1e-3}  # the checkpoint now in b/ is of a finished fit of CGAN
    redo = create_translator("cgan", other)
    assert redo.fit_pairs(depth, foreground, tmp_path / "b", settings).resumed_from_step is None
    assert "another fit" in caplog.text


def test_sigint_stops_after_saving_then_resumes(tmp_path: Path) -> None:
    """Ctrl-C: the step in progress finishes, a checkpoint is written, KeyboardInterrupt."""

    class CtrlC(Callback):
        def on_train_batch_end(self, trainer: Any, *args: Any) -> None:
            if trainer.global_step == 6:
                os.kill(os.getpid(), signal.SIGINT)

    depth, foreground = tiny_pairs(n=20, size=32)
    settings = {**QUIET, EVERY_KEY: 100}  # no periodic save before the interrupt
    straight = create_translator("cgan", CGAN)
    straight.fit_pairs(depth, foreground, tmp_path / "a", settings)
    with pytest.raises(KeyboardInterrupt):
        create_translator("cgan", CGAN).fit_pairs(
            depth, foreground, tmp_path / "b", {**settings, "callbacks": [CtrlC()]}
        )
    ckpt = torch.load(tmp_path / "b/checkpoints/last.ckpt", weights_only=True)
    assert ckpt["global_step"] == 8  # the SIGINT lands mid-step; that step is finished first
    resumed = create_translator("cgan", CGAN)
    assert resumed.fit_pairs(depth, foreground, tmp_path / "b", settings).resumed_from_step == 8
    _same(straight.state_dict(), resumed.state_dict())


# --------------------------------------------------------------------------- real SIGKILL
RECIPE = """
name: resume
trainer: {checkpoint_every_n_steps: 10, enable_progress_bar: false}
stages:
  - name: braille
    kind: braille_data
    config: {chars: ABC, n_finetune: 24, n_test: 12, n_classifier: 60, n_classifier_test: 24,
             image_size: 32}
  - name: fit_cgan
    kind: fit_translator
    inputs: {braille: braille}
    config:
      translator: cgan
      eval_pairs: 8
      translator_config: {max_steps: 60, batch_size: 8, generator_channels: 8,
                          discriminator_channels: 8, num_downs: 3}
  - name: translated
    kind: translate
    inputs: {data: braille, translator: fit_cgan}
  - name: classify
    kind: classify
    inputs: {data: braille, images: translated}
    config: {row: cgan, classifier: {width: 4, epochs: 4, batch_size: 8}}
  - name: report
    kind: report
    inputs: {rows: [classify]}
"""


def _fit_command(recipe: Path, run_dir: Path) -> list[str]:
    return [sys.executable, "-m", "tactile_bench", "--threads", "1", "fit", str(recipe),
            "--run-dir", str(run_dir), "--no-progress"]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["fit_cgan", "classify"])
def test_sigkill_during_training_then_rerun_matches(tmp_path: Path, stage: str) -> None:
    """The issue's experiment: SIGKILL a recipe once its training stage has checkpointed,
    rerun the same command, compare with an uninterrupted run (about 70 s)."""
    recipe = tmp_path / "resume.yaml"
    recipe.write_text(RECIPE)
    env = dict(os.environ, TACTILE_BENCH_NO_WANDB="1")
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    subprocess.run(_fit_command(recipe, straight), env=env, check=True, capture_output=True)

    sub = "seed0/" if stage == "classify" else ""
    pattern = f"{killed}/{stage}-*/{sub}checkpoints/last.ckpt"
    proc = subprocess.Popen(_fit_command(recipe, killed), env=env, stderr=subprocess.DEVNULL)
    while proc.poll() is None and not glob.glob(pattern):
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    (ckpt,) = glob.glob(pattern)
    step = torch.load(ckpt, weights_only=True)["global_step"]
    assert not glob.glob(f"{killed}/{stage}-*/_done.json")  # killed in that stage

    rerun = subprocess.run(_fit_command(recipe, killed), env=env, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert f"resuming from {ckpt} (step {step})" in rerun.stderr
    assert (straight / "results.md").read_text() == (killed / "results.md").read_text()
    outputs = [
        {s["name"]: s["outputs"] for s in json.loads((d / "run.json").read_text())["stages"]}
        for d in (straight, killed)
    ]
    assert outputs[0] == outputs[1]  # every output file of every stage has the same sha256
