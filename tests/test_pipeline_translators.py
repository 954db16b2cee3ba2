"""Pretrain on the corpus -> fine-tune on braille -> translate -> classify, through recipes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tactile_bench.cli import main
from tactile_bench.hardware import resolve_precision

RECIPE = """
name: chain
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 20, n_test: 16, n_classifier: 40}
  - name: corpus
    kind: ycb_slide_data
    config: {n_pairs: 30, objects: [005_tomato_soup_can]}
  - name: pretrain
    kind: fit_translator
    inputs: {corpus: corpus}
    config: {translator: colour_match, translator_config: {max_steps: 4, batch_size: 8}}
  - name: finetune
    kind: fit_translator
    inputs: {braille: braille, init: pretrain}
    config:
      translator: colour_match
      fraction: 0.5
      translator_config: {max_steps: 4, batch_size: 8}
  - name: translated
    kind: translate
    inputs: {data: braille, translator: finetune}
  - name: classify
    kind: classify
    inputs: {data: braille, images: translated}
    config:
      row: diffusion
      finetune_fraction: 0.5
      finetune_epochs: 1
      classifier: {width: 4, epochs: 1}
  - name: report
    kind: report
    inputs: {rows: [classify]}
"""


def test_pretrain_finetune_translate_classify(tmp_path: Path) -> None:
    path = tmp_path / "chain.yaml"
    path.write_text(RECIPE)
    run_dir = tmp_path / "run"
    assert main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"]) == 0
    run = json.loads((run_dir / "run.json").read_text())
    dirs = {s["name"]: run_dir / s["directory"] for s in run["stages"]}

    pretrain = json.loads((dirs["pretrain"] / "metrics.json").read_text())
    finetune = json.loads((dirs["finetune"] / "metrics.json").read_text())
    assert pretrain["fit_pairs"] > 0 and pretrain["initialised_from"] is None
    assert finetune["initialised_from"] == "pretrain"
    assert finetune["fit_pairs"] == 10  # half of 20, stratified over two characters
    assert 0.0 < finetune["heldout"]["ssim"] <= 1.0
    auto = resolve_precision("auto")  # translator precision defaults to auto
    assert pretrain["compute_precision"] == finetune["compute_precision"] == auto

    translated = json.loads((dirs["translated"] / "metrics.json").read_text())
    assert translated["translator"] == "colour_match"
    assert translated["test_similarity"]["mse"] >= 0.0
    assert translated["compute_precision"] == "32-true"  # colour_match translates in fp32
    (row,) = json.loads((run_dir / "results.json").read_text())["rows"]
    assert row["row"] == "diffusion"
    summary = json.loads((dirs["classify"] / "metrics.json").read_text())["summary"]
    assert summary["finetune_fraction"] == 0.5
    assert summary["compute_precision"] == auto
    assert (dirs["classify"] / "seed0" / "finetune" / "checkpoints" / "last.ckpt").exists()


def test_fit_needs_exactly_one_data_source(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(RECIPE.replace("inputs: {braille: braille, init: pretrain}", "inputs: {}"))
    assert main(["fit", str(path), "--run-dir", str(tmp_path / "run")]) == 2
    assert "exactly one of" in capsys.readouterr().err


def test_recipe_trains_on_a_real_ycb_slide_folder(tmp_path: Path) -> None:
    """The same stage reads the original YCB-Slide layout when its source is a path."""
    from data.make_layouts import make_ycb_slide_real

    make_ycb_slide_real(tmp_path / "ycb", "004_sugar_box", n_frames=6, datasets=2)
    recipe = tmp_path / "real_corpus.yaml"
    recipe.write_text(
        "name: real_corpus\nstages:\n"
        "  - {name: corpus, kind: ycb_slide_data, config: {source: ycb}}\n"
        "  - name: pretrain\n    kind: fit_translator\n    inputs: {corpus: corpus}\n"
        "    config: {translator: colour_match, translator_config: {max_steps: 3, batch_size: 4}}\n"
    )
    run_dir = tmp_path / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    run = json.loads((run_dir / "run.json").read_text())
    corpus_dir = run_dir / run["stages"][0]["directory"]
    manifest = json.loads((corpus_dir / "manifest.json").read_text())
    assert manifest["n_train"] > 0 and manifest["n_test"] > 0  # one recording each
    splits = {s["trajectory"]: s["split"] for s in manifest["shards"]}
    assert sorted(splits.values()) == ["test", "train"]
    metrics = json.loads((run_dir / run["stages"][1]["directory"] / "metrics.json").read_text())
    assert metrics["fit_pairs"] == manifest["n_train"]


def test_missing_real_folder_is_a_recipe_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: r\nstages:\n  - {name: corpus, kind: ycb_slide_data, config: {source: nowhere}}\n"
    )
    assert main(["fit", str(recipe), "--run-dir", str(tmp_path / "run")]) == 2
    assert "nowhere" in capsys.readouterr().err


COMPARE = """
name: compare
stages:
  - name: braille
    kind: braille_data
    config: {chars: ABC, n_finetune: 30, n_test: 12, n_classifier: 30, n_classifier_test: 9}
  - name: fit_cgan
    kind: fit_translator
    inputs: {braille: braille}
    config: {translator: cgan, translator_config: {max_steps: 2, batch_size: 4}}
  - name: translate_sim
    kind: translate
    inputs: {data: braille}
    config: {translator: sim, sets: [test]}
  - name: translate_cgan
    kind: translate
    inputs: {data: braille, translator: fit_cgan}
    config: {sets: [test]}
  - name: compare
    kind: compare_translators
    inputs: {data: braille, translated: [translate_sim, translate_cgan]}
    config: {encoder_steps: 5, samples: 3}
"""


def test_compare_translators_scores_each_on_the_same_test_set(tmp_path: Path) -> None:
    path = tmp_path / "compare.yaml"
    path.write_text(COMPARE)
    run_dir = tmp_path / "run"
    assert main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"]) == 0
    run = json.loads((run_dir / "run.json").read_text())
    compare_dir = run_dir / run["stages"][-1]["directory"]
    rows = json.loads((compare_dir / "similarity.json").read_text())["rows"]
    assert [r["translator"] for r in rows] == ["sim", "cgan"]
    for r in rows:
        assert 0.0 < r["ssim"] <= 1.0 and r["mse"] > 0.0 and r["kid"] == r["kid"]
    assert rows[1]["paper_ssim"] == 0.879
    assert "| cgan |" in (run_dir / "similarity.md").read_text()
    assert (run_dir / "samples.png").read_bytes()[:4] == b"\x89PNG"


SEEDS_RECIPE = """
name: seeds
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 12, n_test: 8, n_classifier: 24, n_classifier_test: 8}
  - name: classify
    kind: classify
    inputs: {data: braille}
    config:
      row: real
      train_images: real
      seeds: [0, 1]
      batch_seeds: BATCH
      parallel_seeds: PARALLEL
      finetune_fraction: 0.5
      finetune_epochs: 1
      classifier: {width: 4, blocks: [1, 1, 1, 1], epochs: 2}
"""


def test_parallel_seeds_train_the_models_sequential_training_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two seeds in two one-thread worker processes (base training and real fine-tuning)
    give the same weights and scores as the two trained in turn here on one thread."""
    import torch

    monkeypatch.setenv("TACTILE_BENCH_NO_WANDB", "1")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the workers get 1 // 2 -> 1 thread: same arithmetic
    try:
        out = {}
        for parallel in (1, 2):
            path = tmp_path / f"seeds{parallel}.yaml"
            recipe = SEEDS_RECIPE.replace("PARALLEL", str(parallel))
            path.write_text(recipe.replace("BATCH", "false"))
            run_dir = tmp_path / f"run{parallel}"
            assert main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"]) == 0
            (stage,) = run_dir.glob("classify-*")
            out[parallel] = stage
    finally:
        torch.set_num_threads(threads)
    for seed in (0, 1):
        sequential = torch.load(out[1] / f"model_seed{seed}.pt", weights_only=True)
        parallel = torch.load(out[2] / f"model_seed{seed}.pt", weights_only=True)
        for name, value in sequential["state_dict"].items():
            assert torch.equal(value, parallel["state_dict"][name]), (seed, name)
        assert (out[2] / f"seed{seed}" / "finetune" / "checkpoints" / "last.ckpt").exists()
    scores = [json.loads((d / "metrics.json").read_text())["per_seed"] for d in out.values()]
    assert [s["test"]["accuracy"] for s in scores[0]] == [s["test"]["accuracy"] for s in scores[1]]


def test_batched_seeds_train_the_models_one_at_a_time_training_does(tmp_path: Path) -> None:
    """A classify stage's seeds as one stacked model (the default), base training and real
    fine-tuning, against the same seeds one at a time: each seed's weights agree within
    float tolerance (grouped convolutions sum in another order, see
    tests/test_classify_stacked.py) and its scores are the same."""
    import torch

    out = {}
    for batch in ("true", "false"):
        path = tmp_path / f"seeds_{batch}.yaml"
        path.write_text(SEEDS_RECIPE.replace("PARALLEL", "1").replace("BATCH", batch))
        run_dir = tmp_path / f"run_{batch}"
        assert main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"]) == 0
        (out[batch],) = run_dir.glob("classify-*")
    assert (out["true"] / "seeds" / "finetune" / "checkpoints" / "last.ckpt").exists()
    for seed in (0, 1):
        alone = torch.load(out["false"] / f"model_seed{seed}.pt", weights_only=True)
        batched = torch.load(out["true"] / f"model_seed{seed}.pt", weights_only=True)
        for name, value in alone["state_dict"].items():
            torch.testing.assert_close(
                batched["state_dict"][name], value, rtol=1e-4, atol=1e-4, msg=name
            )
    scores = [json.loads((d / "metrics.json").read_text())["per_seed"] for d in out.values()]
    assert [s["test"]["accuracy"] for s in scores[0]] == [s["test"]["accuracy"] for s in scores[1]]


TWO_FITS = """
name: two_fits
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 20, n_test: 16, n_classifier: 40}
  - name: first
    kind: fit_translator
    inputs: {braille: braille}
    config: {translator: colour_match, translator_config: {max_steps: 2, batch_size: 8}}
  - name: second
    kind: fit_translator
    inputs: {braille: braille}
    config: {translator: colour_match, translator_config: {max_steps: 3, batch_size: 8}}
"""


def test_each_fit_logs_to_its_own_wandb_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """wandb keeps one run a process: a stage that leaves its run open makes the next
    stage's fit log into it (the second stage then has no run of its own)."""
    pytest.importorskip("wandb")
    monkeypatch.delenv("TACTILE_BENCH_NO_WANDB", raising=False)
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_BASE_URL", "http://127.0.0.1:9")  # would fail if it went online
    path = tmp_path / "two.yaml"
    path.write_text(TWO_FITS)
    run_dir = tmp_path / "run"
    assert main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"]) == 0
    run = json.loads((run_dir / "run.json").read_text())
    dirs = {s["name"]: run_dir / s["directory"] for s in run["stages"]}
    runs = {
        name: list((dirs[name] / "wandb").glob("offline-run-*")) for name in ("first", "second")
    }
    assert len(runs["first"]) == 1 and len(runs["second"]) == 1
    assert runs["first"][0].name != runs["second"][0].name
