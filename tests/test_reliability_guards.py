"""Training that goes wrong says so: a NaN/inf loss stops the fit (last good checkpoint kept),
a diverging GAN is detected and recorded in the stage's metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.errors import TactileBenchError
from tactile_bench.testing import tiny_pairs
from tactile_bench.training import EVERY_KEY, NonFiniteLoss
from tactile_bench.translators import create_translator
from tactile_bench.translators.cgan import lightning_model as cgan_module
from tactile_bench.translators.cgan.divergence import DivergenceMonitor


@pytest.fixture(autouse=True)
def _no_wandb(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_BENCH_NO_WANDB", "1")  # 1.5 s a logger; CSV is enough here


SMALL = {"generator_channels": 4, "discriminator_channels": 4, "batch_size": 6}
SETTINGS = {"enable_progress_bar": False, EVERY_KEY: 2}


def _nan_after(real: Any, calls: int) -> Any:
    """``real`` for the first ``calls`` calls, then its first output turned NaN."""
    count = {"n": 0}

    def patched(*args: Any, **kwargs: Any) -> Any:
        out = real(*args, **kwargs)
        count["n"] += 1
        if count["n"] <= calls:
            return out
        if isinstance(out, tuple):
            return (out[0] * float("nan"), *out[1:])
        return out * float("nan")

    return patched


def _assert_good_checkpoint(path: Path, before: int) -> None:
    ckpt = torch.load(path, weights_only=True)
    assert ckpt["global_step"] < before
    for name, tensor in ckpt["state_dict"].items():
        if tensor.is_floating_point():
            assert torch.isfinite(tensor).all(), name


def test_nan_loss_stops_a_manual_optimisation_fit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cgan_module, "generator_loss", _nan_after(cgan_module.generator_loss, 5))
    translator = create_translator("cgan", {**SMALL, "max_steps": 20})
    depth, foreground = tiny_pairs(n=12, size=32)
    with pytest.raises(NonFiniteLoss) as info:
        translator.fit_pairs(depth, foreground, tmp_path, SETTINGS)
    message = str(info.value)
    assert "g_loss = nan at step 12" in message and "last good checkpoint" in message
    assert "\n" not in message
    _assert_good_checkpoint(tmp_path / "checkpoints/last.ckpt", before=12)


def test_inf_loss_stops_an_automatic_optimisation_fit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    translator = create_translator("colour_match", {"max_steps": 20, "batch_size": 6})
    real = type(translator).training_step
    count = {"n": 0}

    def step(self: Any, batch: Any, batch_idx: int) -> torch.Tensor:
        count["n"] += 1
        loss = real(self, batch, batch_idx)
        return loss * float("inf") if count["n"] > 6 else loss

    monkeypatch.setattr(type(translator), "training_step", step)
    depth, foreground = tiny_pairs(n=12, size=32)
    with pytest.raises(TactileBenchError, match=r"loss = inf at step 7"):
        translator.fit_pairs(depth, foreground, tmp_path, SETTINGS)
    _assert_good_checkpoint(tmp_path / "checkpoints/last.ckpt", before=7)


RECIPE = """
name: guard
trainer: {checkpoint_every_n_steps: 4, enable_progress_bar: false}
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 12, n_test: 8, n_classifier: 8, n_classifier_test: 8,
             image_size: 32}
  - name: fit_cgan
    kind: fit_translator
    inputs: {braille: braille}
    config:
      translator: cgan
      eval_pairs: 4
      translator_config: {max_steps: MAX, batch_size: 4, generator_channels: 4,
                          discriminator_channels: 4, num_downs: 3, LR}
"""


def _recipe(tmp_path: Path, max_steps: int, lr: str) -> Path:
    path = tmp_path / "guard.yaml"
    path.write_text(RECIPE.replace("MAX", str(max_steps)).replace("LR", lr))
    return path


def test_nan_through_the_command_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cgan_module, "generator_loss", _nan_after(cgan_module.generator_loss, 5))
    recipe = _recipe(tmp_path, 10, "lr: 0.0002")
    code = main(["fit", str(recipe), "--run-dir", str(tmp_path / "run"), "--no-progress"])
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(errors) == 1
    assert errors[0].startswith("error: stage fit_cgan: translator 'cgan' fit in ")
    assert "g_loss = nan at step 12" in errors[0]
    (stage_dir,) = (tmp_path / "run").glob("fit_cgan-*")
    assert not (stage_dir / "_done.json").exists()  # not marked finished
    _assert_good_checkpoint(stage_dir / "checkpoints/last.ckpt", before=12)


def test_diverging_gan_is_recorded_in_the_stage_metrics(tmp_path: Path) -> None:
    """lr 0.5 blows the game up (D loss averages > 3 for 20 steps); metrics say when and why."""
    # fp32 on every CPU: bf16 (auto on AVX-512-BF16) reaches the blow-up by another path
    recipe = _recipe(tmp_path, 150, "lr: 0.5, divergence_window: 20, precision: 32-true")
    # on the CPU everywhere: a GPU's kernels reach the blow-up by another path too
    args = ["--run-dir", str(tmp_path / "run"), "--no-progress", "--set", "trainer.accelerator=cpu"]
    assert main(["fit", str(recipe), *args]) == 0
    (metrics,) = (tmp_path / "run").glob("fit_cgan-*/metrics.json")
    divergence = json.loads(metrics.read_text())["divergence"]
    assert divergence is not None and divergence["step"] > 20
    assert "D loss average" in divergence["why"]


def test_healthy_gan_is_not_flagged(tmp_path: Path) -> None:
    translator = create_translator("cgan", {**SMALL, "max_steps": 60, "divergence_window": 20})
    depth, foreground = tiny_pairs(n=24, size=32)
    translator.fit_pairs(depth, foreground, tmp_path, SETTINGS)
    assert translator.fit_diagnostics() == {"divergence": None}
    assert translator.monitor.steps == 60


def _feed(monitor: DivergenceMonitor, values: list[tuple[float, float, float]]) -> Any:
    events = [monitor.update(*v) for v in values]
    return next((e for e in events if e is not None), None)


def test_monitor_flags_a_rising_l1() -> None:
    monitor = DivergenceMonitor(window=10, factor=3.0)
    falling = [(0.4, 1.0, 0.2 / (1 + i / 10)) for i in range(40)]
    assert _feed(monitor, falling) is None
    event = _feed(monitor, [(0.4, 1.0, 0.4)] * 40)
    assert event is not None and "L1" in event["why"] and event["step"] > 40


def test_monitor_ignores_a_short_discriminator_win_but_not_a_long_one() -> None:
    monitor = DivergenceMonitor(window=10)
    balanced, d_wins = (0.4, 1.0, 0.05), (0.001, 9.0, 0.05)
    assert _feed(monitor, [balanced] * 20 + [d_wins] * 12 + [balanced] * 30) is None
    event = _feed(monitor, [d_wins] * 40)
    assert event is not None and "discriminator wins" in event["why"]


def test_monitor_state_round_trips() -> None:
    a, b = DivergenceMonitor(window=5), DivergenceMonitor(window=5)
    values = [(0.4, 1.0, 0.1)] * 8
    _feed(a, values)
    b.load_state_dict(json.loads(json.dumps(a.state_dict())))
    later = [(5.0, 5.0, 0.1)] * 12
    assert _feed(a, later) == _feed(b, later) is not None
