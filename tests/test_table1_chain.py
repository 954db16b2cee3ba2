"""recipes/table1.yaml and quick.yaml: every paper row through the real chain, shrunk to seconds.

The test reads the shipped table1 recipe, keeps its stages, inputs and rows, and only makes
every size tiny, so the chain users run is the chain tested.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch
import yaml
from pydantic import ValidationError

from tactile_bench.cli import main
from tactile_bench.data.braille import SECOND_UNIT_SET, BrailleSet
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.report.table import EXTRA_ROWS, PAPER_TABLE
from tactile_bench.testing import shrink_recipe

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def table_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("table1")
    doc = yaml.safe_load((REPO / "recipes" / "table1.yaml").read_text())
    recipe = tmp / "table1_tiny.yaml"
    recipe.write_text(yaml.safe_dump(shrink_recipe(doc)))
    run_dir = tmp / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    return run_dir


def _stage_dirs(run_dir: Path) -> dict[str, Path]:
    run = json.loads((run_dir / "run.json").read_text())
    return {s["name"]: run_dir / s["directory"] for s in run["stages"]}


def test_table_has_every_paper_row_with_mean_and_std(table_run: Path) -> None:
    table = json.loads((table_run / "table.json").read_text())
    ours = ["calibrated", "sim_aug_image"]  # rows the paper does not have, after its nine
    assert [r["row"] for r in table["rows"]] == list(PAPER_TABLE) + ours
    for row in table["rows"]:
        for metric in ("accuracy", "precision", "recall"):
            assert set(row[metric]) == {"mean", "std"}
            assert 0.0 <= row[metric]["mean"] <= 1.0
        assert row["seeds"] == [0, 1]
        if row["row"] in PAPER_TABLE:
            assert row["paper"]["accuracy"] == PAPER_TABLE[row["row"]].accuracy
        else:
            assert row["paper"] is None
        assert row["second_unit"] == "digit-b"  # every row is also tested on the second unit
        assert set(row["second_unit_accuracy"]) == {"mean", "std"}
        assert 0.0 <= row["second_unit_accuracy"]["mean"] <= 1.0
    translators = {s["translator"] for s in table["similarity"]}
    assert translators == {"sim", "lighting_aug", "cgan", "diffusion", "calibrated"}
    timed = {s["name"] for s in table["stages"]}
    assert {"braille", "pretrain_diffusion", "classify_real"} <= timed
    assert all(s["wall_time_s"] >= 0 for s in table["stages"])
    assert table["versions"]["torch"]


def test_report_md_and_self_contained_html(table_run: Path) -> None:
    md = (table_run / "report.md").read_text()
    for heading in ("ours beside the paper", "claims, checked", "Per-class", "Confusion", "time"):
        assert heading in md
    for text in (md, (table_run / "results.md").read_text()):
        assert "| accuracy % (ours) | accuracy % on second unit (digit-b) |" in text
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md):
        assert (table_run / link).is_file(), link  # links resolve from the run directory
    html = (table_run / "report.html").read_text()
    sources = re.findall(r'src="([^"]+)"', html)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "Tactile diffusion" in html and "cGAN" in html


def test_second_unit_renders_the_same_test_contacts_and_is_seen_only_by_classify(
    table_run: Path,
) -> None:
    dirs = _stage_dirs(table_run)
    test = BrailleSet.load(dirs["braille"] / "classifier_test.npz")
    unit = BrailleSet.load(dirs["braille"] / f"{SECOND_UNIT_SET}.npz")
    assert torch.equal(unit.depth, test.depth) and torch.equal(unit.sim, test.sim)
    assert (unit.real.float() - test.real.float()).abs().mean() > 5  # digit-b's, not digit's
    run = json.loads((table_run / "run.json").read_text())
    braille = next(s for s in run["stages"] if s["name"] == "braille")
    assert braille["config"]["second_unit"] == "digit-b"
    metrics = json.loads((dirs["braille"] / "_done.json").read_text())["metrics"]
    assert metrics["content"][SECOND_UNIT_SET] == {"has_sim": True, "has_real": True}
    summary = json.loads((dirs["classify_real"] / "metrics.json").read_text())["summary"]
    assert summary["second_unit"] == "digit-b" and summary["second_unit_accuracy"]["mean"] >= 0
    # no stage can be pointed at it for anything else: no translator or classifier trains on it
    recipe = load_recipe(REPO / "recipes" / "table1.yaml")
    for name in ("classify_real", "finetune_diffusion", "translate_sim"):
        stage = recipe.stage(name)
        key = "sets" if stage.kind.name == "translate" else "train_set"
        value = [SECOND_UNIT_SET] if key == "sets" else SECOND_UNIT_SET
        with pytest.raises(ValidationError, match=key):
            stage.kind.config_model(**(stage.config.model_dump() | {key: value}))


def test_finetuning_rows_start_from_their_base_rows_models(table_run: Path) -> None:
    dirs = _stage_dirs(table_run)
    # the seeds train as one batched model (batch_seeds): its files are under seeds/
    for row in ("classify_sim_ft20", "classify_sim_ft80", "classify_sim_ft100"):
        seeds_dir = dirs[row] / "seeds"
        assert (seeds_dir / "finetune").is_dir()
        assert not (seeds_dir / "checkpoints").exists()  # no second base training
    base = dirs["classify_sim"] / "seeds"
    assert (base / "checkpoints").is_dir() and not (base / "finetune").exists()


# table1 reports the paper's rows over 3 seeds; quick.yaml's first look over 2 (a std needs 2)
@pytest.mark.parametrize(("name", "min_seeds"), [("table1", 3), ("quick", 2)])
def test_shipped_recipes_validate_and_report_all_nine_rows(
    repo: Path, name: str, min_seeds: int
) -> None:
    recipe = load_recipe(repo / "recipes" / f"{name}.yaml")
    report = recipe.stage("report")
    rows = [recipe.stage(r).config.row for r in report.inputs["rows"]]
    assert rows == [*PAPER_TABLE, "calibrated", "sim_aug_image"]  # the paper's nine, then ours
    assert set(rows[len(PAPER_TABLE) :]) <= set(EXTRA_ROWS)  # ours carry a label in the table
    for stage in recipe.stages:
        if stage.kind.name == "classify":
            assert len(stage.config.seeds) >= min_seeds


def test_set_on_one_stage_does_not_leak_through_yaml_anchors(repo: Path) -> None:
    recipe = load_recipe(repo / "recipes" / "table1.yaml", ["classify_sim.classifier.width=4"])
    assert recipe.stage("classify_sim").config.classifier.width == 4
    assert recipe.stage("classify_cgan").config.classifier.width == 16
