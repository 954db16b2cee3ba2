"""Translator registry and the translator contract for every registered translator."""

from __future__ import annotations

from importlib.metadata import EntryPoint
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.testing import TranslatorContract
from tactile_bench.translators import registry
from tactile_bench.translators.sim import SimTranslator


class TestSimContract(TranslatorContract):
    name = "sim"


class TestColourMatchPluginContract(TranslatorContract):
    """The example plugin in plugins/ (installed by the README's test command)."""

    name = "colour_match"
    tiny_config = {"max_steps": 3, "batch_size": 4}

    def test_fit_moves_towards_real(self, tmp_path: Path) -> None:
        from tactile_bench.testing import tiny_pairs

        depth, foreground = tiny_pairs(n=16, size=self.size)
        translator = self.make()
        gen = torch.Generator().manual_seed(0)
        before = torch.mean((translator.translate_foreground(depth, gen) - foreground) ** 2)
        translator = type(translator)({"max_steps": 60, "batch_size": 16, "lr": 0.05})
        translator.fit_pairs(depth, foreground, tmp_path, {"enable_progress_bar": False})
        gen = torch.Generator().manual_seed(0)
        with torch.no_grad():
            after = torch.mean((translator.translate_foreground(depth, gen) - foreground) ** 2)
        assert after < 0.7 * before


def test_builtins_and_plugin_are_discovered() -> None:
    found = registry.discover()
    assert found["sim"].target == "tactile_bench.translators.sim:SimTranslator"
    assert "colour_match" in found


def _fake_entry_points(*pairs: tuple[str, str]):
    def fake(group: str) -> list[EntryPoint]:
        assert group == registry.GROUP
        return [EntryPoint(name=n, value=v, group=group) for n, v in pairs]

    return fake


def test_duplicate_name_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        registry,
        "entry_points",
        _fake_entry_points(
            ("sim", "tactile_bench.translators.sim:SimTranslator"), ("sim", "someone_else:Sim")
        ),
    )
    with pytest.raises(TactileBenchError, match="registered twice"):
        registry.discover()


def test_broken_plugin_breaks_only_itself(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        registry,
        "entry_points",
        _fake_entry_points(
            ("sim", "tactile_bench.translators.sim:SimTranslator"),
            ("broken", "no_such_module_xyz:Thing"),
            ("notone", "tactile_bench.errors:TactileBenchError"),
        ),
    )
    assert registry.translator_class("sim") is SimTranslator
    with pytest.raises(TactileBenchError, match="failed to import"):
        registry.translator_class("broken")
    with pytest.raises(TactileBenchError, match="not a Translator"):
        registry.translator_class("notone")


def test_list_survives_a_broken_plugin(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from tactile_bench.cli import main

    monkeypatch.setattr(
        registry,
        "entry_points",
        _fake_entry_points(
            ("sim", "tactile_bench.translators.sim:SimTranslator"),
            ("broken", "no_such_module_xyz:Thing"),
        ),
    )
    assert main(["list", "translators"]) == 0
    out = capsys.readouterr().out
    assert "sim" in out and "broken" in out and "failed to import" in out


def test_checkpoint_of_another_translator_is_rejected(tmp_path: Path) -> None:
    from tactile_bench_colour_match import ColourMatchTranslator

    path = SimTranslator().save(tmp_path / "sim.pt")
    with pytest.raises(TactileBenchError, match="checkpoint of translator 'sim'"):
        ColourMatchTranslator.load(path)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(TactileBenchError, match="junk.pt"):
        SimTranslator.load(tmp_path / "junk.pt")


def test_bad_translator_config_names_the_key() -> None:
    with pytest.raises(TactileBenchError, match="colour_match.*'lr'"):
        registry.create_translator("colour_match", {"lr": "fast"})


@pytest.mark.parametrize("native", [False, True])
def test_fit_trains_in_the_precision_auto_resolves_to(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, native: bool
) -> None:
    """Every translator's fit: the config's ``precision`` (default auto) reaches the Trainer,
    and a recipe's ``trainer: {precision: ...}`` wins over it."""
    from lightning.pytorch.callbacks import Callback

    from tactile_bench import hardware
    from tactile_bench.testing import tiny_pairs
    from tactile_bench.translators import create_translator

    class Seen(Callback):
        def __init__(self) -> None:
            self.precision: list[str] = []

        def on_train_start(self, trainer: Any, pl_module: Any) -> None:
            self.precision.append(trainer.precision)

    monkeypatch.setattr(hardware, "native_bf16", lambda device="cpu": native)
    depth, foreground = tiny_pairs(n=4, size=16)
    seen = Seen()
    for run, trainer in enumerate([{}, {"precision": "32-true"}]):
        translator = create_translator("colour_match", {"max_steps": 1, "batch_size": 4})
        assert translator.config.precision == "auto"
        settings = {"enable_progress_bar": False, "callbacks": [seen], **trainer}
        translator.fit_pairs(depth, foreground, tmp_path / str(run), settings)
    assert seen.precision == ["bf16-mixed" if native else "32-true", "32-true"]
