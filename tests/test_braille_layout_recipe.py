"""A braille recipe pointed at real data in the Tactile-Diffusion layout runs unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from data.make_layouts import make_braille_layout

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet

RECIPE = """
name: layout
stages:
  - name: braille
    kind: braille_data
    config: {{chars: "AB#", source: {source}, n_classifier: 30}}
  - name: translate_sim
    kind: translate
    inputs: {{data: braille}}
    config: {{translator: sim}}
  - name: classify_sim
    kind: classify
    inputs: {{data: braille, images: translate_sim}}
    config: {{row: sim, classifier: {{width: 4, epochs: 1}}}}
  - name: classify_real
    kind: classify
    inputs: {{data: braille}}
    config: {{row: real, train_images: real, {real_set}classifier: {{width: 4, epochs: 1}}}}
  - name: report
    kind: report
    inputs: {{rows: [classify_sim, classify_real]}}
"""


def _write(tmp_path: Path, real_set: str = "train_set: finetune, ") -> Path:
    make_braille_layout(tmp_path / "braille", letters=("a", "b", "#"), per_letter=4)
    recipe = tmp_path / "layout.yaml"
    # a relative source resolves from the recipe's folder
    recipe.write_text(RECIPE.format(source="braille", real_set=real_set))
    return recipe


def test_recipe_reads_the_tactile_diffusion_layout(tmp_path: Path) -> None:
    recipe = _write(tmp_path)
    run_dir = tmp_path / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    stages = {
        s["name"]: run_dir / s["directory"]
        for s in json.loads((run_dir / "run.json").read_text())["stages"]
    }
    finetune = BrailleSet.load(stages["braille"] / "finetune.npz")
    test = BrailleSet.load(stages["braille"] / "test.npz")
    split_train = BrailleSet.load(stages["braille"] / "split_train.npz")
    # finetune: the whole pool (braille_clf); split_train/test: the split file's lists
    assert (len(finetune), len(split_train), len(test)) == (12, 9, 3)
    assert sorted(set(finetune.labels.tolist())) == [0, 1, 2]  # a, b, # as chars "AB#"
    # the fixture's masks are a flat grey level 20: 0.6 mm everywhere
    assert abs(float(finetune.depth.mean()) - 0.6) < 1e-3
    assert finetune.sim.float().std() > 0  # rendered by our simulator over that depth
    results = json.loads((run_dir / "results.json").read_text())
    rows = {r["row"]: r for r in results["rows"]}
    assert rows["real"]["extra"]["n_test"] == 12  # the release's real/color frames
    assert rows["sim"]["sim_accuracy"] is None  # no sim images of real/color frames
    # the report says what the test set was: the release's real frames, not surrogate ones
    assert "real DIGIT frames of the braille release" in (run_dir / "results.md").read_text()


def test_real_row_on_the_simulated_grid_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recipe = _write(tmp_path, real_set="")
    assert main(["fit", str(recipe), "--run-dir", str(tmp_path / "run"), "--no-progress"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and "classify_real" in err[0] and "train_set: finetune" in err[0]
    assert "Traceback" not in "\n".join(err)


def test_missing_layout_folder_fails_before_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recipe = tmp_path / "layout.yaml"
    recipe.write_text(RECIPE.format(source="nowhere", real_set=""))
    assert main(["fit", str(recipe), "--run-dir", str(tmp_path / "run"), "--no-progress"]) == 2
    assert "real_fine_tuning" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
