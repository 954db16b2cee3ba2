"""recipes/paper.yaml: the paper's own diffusion model, as its authors trained it, through the
same chain and report as table1.yaml (issue 39). Its sizes need a GPU; here the settings are
checked against the paper and the chain runs shrunk, as tests/test_table1_chain.py does."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from tactile_bench.cli import main
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.testing import shrink_recipe
from tactile_bench.translators.diffusion import PRESETS, build_unet

REPO = Path(__file__).resolve().parents[1]
RECIPE = REPO / "recipes" / "paper.yaml"


def _stages() -> dict[str, Any]:
    return {stage.name: stage for stage in load_recipe(RECIPE).stages}


def test_the_paper_unet_is_tactile_diffusions() -> None:
    """Channel multipliers 1-2-4-8, two ResNet blocks a level, attention at 32 x 32 only."""
    spec = PRESETS["paper"]
    base = spec.block_out_channels[0]
    assert [c // base for c in spec.block_out_channels] == [1, 2, 4, 8]
    assert spec.layers_per_block == 2
    unet = build_unet(spec, 64)
    sizes = [64 // 2**level for level in range(len(spec.down_block_types))]
    with_attention = [
        size
        for size, block in zip(sizes, unet.down_blocks, strict=True)
        if hasattr(block, "attentions")
    ]
    assert with_attention == [32]


def test_paper_recipe_trains_and_samples_as_the_paper() -> None:
    stages = _stages()
    corpus = stages["corpus"].config.n_pairs
    for name in ("pretrain_diffusion", "finetune_diffusion"):
        translator = stages[name].config.translator_config
        assert translator["preset"] == "paper"
        assert translator["prediction"] == "epsilon"
        assert (translator["sampler"], translator["steps"]) == ("ddpm", 500)
        assert (translator["batch_size"], translator["lr"]) == (32, 1e-4)
    pretrain = stages["pretrain_diffusion"].config.translator_config
    # 10 epochs of the corpus's training split (80%, split by trajectory)
    assert pretrain["max_steps"] * 32 == 10 * int(0.8 * corpus)
    assert stages["finetune_diffusion"].config.fraction == 0.2
    assert "translator_config" not in stages["translate_diffusion"].config.model_fields_set
    compare = stages["compare"].inputs["translated"]
    assert {"translate_diffusion", "translate_diffusion_fast"} <= set(compare)
    assert stages["classify_diffusion"].config.seeds == [0, 1, 2]


def test_paper_recipe_runs_shrunk_on_the_cpu(tmp_path: Path) -> None:
    doc = shrink_recipe(yaml.safe_load(RECIPE.read_text()))
    recipe = tmp_path / "paper_tiny.yaml"
    recipe.write_text(yaml.safe_dump(doc))
    run_dir = tmp_path / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    table = json.loads((run_dir / "table.json").read_text())
    rows = {row["row"] for row in table["rows"]}
    assert {"sim", "diffusion", "cgan", "real"} <= rows
    assert (run_dir / "report.md").is_file()
