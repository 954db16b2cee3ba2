"""Every recipe key is documented where it is defined (``Field(description=...)``) and
``list stages`` shows it (issue 20)."""

from __future__ import annotations

import pytest

from tactile_bench.cli import main
from tactile_bench.pipeline.stages import STAGES
from tactile_bench.pipeline.stages.base import config_keys


def test_every_stage_config_key_has_a_description() -> None:
    missing = [
        f"{name}.{key.key}"
        for name, kind in STAGES.items()
        for key in config_keys(kind.config_model)
        if len(key.description.split()) < 2
    ]
    assert missing == []


def test_nested_configs_are_listed_by_dotted_key() -> None:
    keys = {k.key: k for k in config_keys(STAGES["classify"].config_model)}
    assert "classifier.lr" in keys and "classifier" not in keys
    assert keys["row"].default == "required"


def test_list_stages_prints_each_key_with_default_and_meaning(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["list", "stages"]) == 0
    out = capsys.readouterr().out
    for kind in STAGES.values():
        for key in config_keys(kind.config_model):
            assert f"      {key.key}: {key.default}  # {key.description}" in out


def test_a_mistyped_key_is_answered_with_the_nearest_key_and_its_meaning(tmp_path) -> None:
    from tactile_bench.errors import TactileBenchError
    from tactile_bench.pipeline.recipe import load_recipe

    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: typo\nstages:\n  - name: c\n    kind: classify\n"
        "    config: {row: Sim, classifier: {lrr: 0.1}}\n"
    )
    with pytest.raises(TactileBenchError) as info:
        load_recipe(recipe)
    message = str(info.value)
    assert "config.classifier.lrr: Extra inputs are not permitted" in message
    assert "did you mean classifier.lr (Adam learning rate)?" in message
    assert "\n" not in message


def test_every_translator_config_key_has_a_description() -> None:
    from tactile_bench.translators.registry import discover

    missing = [
        f"{name}.{key}"
        for name, entry in discover().items()
        for key, field_info in entry.load().Config.model_fields.items()
        if not field_info.description
    ]
    assert missing == []
