"""Determinism and its record: the same recipe and seed give the same table, and run.json says
what made it (seeds, versions, platform, the hash of every input)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch

from tactile_bench import hardware
from tactile_bench.cli import main
from tactile_bench.hardware import machine_compute
from tactile_bench.io import file_sha256
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.pipeline.runner import stage_key
from tactile_bench.pipeline.stages.report import machine_line
from tactile_bench.sensor.surrogate import PROFILE_DIR

RECIPE = """
name: det
seed: 3
trainer: {enable_progress_bar: false}
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 8, n_test: 8, n_classifier: 40, n_classifier_test: 16,
             image_size: 32, real_sensor: PROFILE}
  - name: translate_sim
    kind: translate
    inputs: {data: braille}
    config: {translator: sim}
  - name: classify_sim
    kind: classify
    inputs: {data: braille, images: translate_sim}
    config: {row: sim, seeds: [0, 1], classifier: {width: 4, epochs: 1, batch_size: 8}}
  - name: report
    kind: report
    inputs: {rows: [classify_sim]}
"""


@pytest.fixture(autouse=True)
def _no_wandb(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_BENCH_NO_WANDB", "1")


@pytest.fixture
def recipe(tmp_path: Path) -> Path:
    profile = tmp_path / "unit.yaml"
    profile.write_text((PROFILE_DIR / "digit.yaml").read_text())
    path = tmp_path / "det.yaml"
    path.write_text(RECIPE.replace("PROFILE", str(profile)))
    return path


def _fit(recipe: Path, run_dir: Path) -> dict:
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    return json.loads((run_dir / "run.json").read_text())


def test_same_recipe_same_seed_same_table(recipe: Path, tmp_path: Path) -> None:
    one, two = _fit(recipe, tmp_path / "one"), _fit(recipe, tmp_path / "two")
    assert (tmp_path / "one/results.md").read_text() == (tmp_path / "two/results.md").read_text()
    # every output is byte-identical except the report's pages and figures, which carry
    # this run's stage wall times; the report's table and numbers are identical
    timed = {"report_md", "report_html", "table_json"}

    def untimed(run: dict) -> list[dict]:
        return [{k: v for k, v in s["outputs"].items() if k not in timed} for s in run["stages"]]

    assert untimed(one) == untimed(two)
    assert [s["directory"] for s in one["stages"]] == [s["directory"] for s in two["stages"]]

    # what run.json records
    assert one["seeds"] == {"recipe": 3, "classify_sim.seeds": [0, 1]}
    for package in (
        "python",
        "tactile_bench",
        "torch",
        "lightning",
        "diffusers",
        "kornia",
        "numpy",
    ):
        assert one["versions"][package], package
    assert one["machine"]["platform"] and one["machine"]["torch_threads"] >= 1
    # what precision: auto gives on this machine, and what each stage ran in
    compute = machine_compute()
    assert {k: one["machine"][k] for k in compute} == compute
    assert one["machine"]["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    stages = {s["name"]: s for s in one["stages"]}
    assert stages["braille"]["compute_precision"] is None  # no networks
    assert stages["translate_sim"]["compute_precision"] == "32-true"  # sim: no autocast
    assert stages["classify_sim"]["compute_precision"] == compute["auto_precision"]
    report = (tmp_path / "one" / "report.md").read_text()
    assert machine_line(compute) in report
    assert "| stage | kind | wall time (s) | cached in this run | precision |" in report
    row = rf"\| classify_sim \| classify \| [\d.]+ \| (yes|no) \| {compute['auto_precision']} \|"
    assert re.search(row, report)
    assert re.search(r"\| braille \| braille_data \| [\d.]+ \| (yes|no) \| — \|", report)
    table = json.loads((tmp_path / "one" / "table.json").read_text())
    assert table["machine"] == compute
    by_name = {s["name"]: s for s in table["stages"]}
    assert by_name["classify_sim"]["compute_precision"] == compute["auto_precision"]
    assert one["recipe_sha256"] == file_sha256(recipe)
    profile = str((tmp_path / "unit.yaml").resolve())
    assert one["inputs"][profile]["sha256"] == file_sha256(tmp_path / "unit.yaml")
    braille = one["stages"][0]
    assert braille["config"]["real_sensor"] == profile
    assert set(braille["outputs"]) >= {"finetune", "test", "classifier"}


def test_editing_a_named_input_file_reruns_its_stage(recipe: Path, tmp_path: Path) -> None:
    """The profile's content is part of the stage key: an edit is never silently ignored."""
    recipe.write_text(recipe.read_text().split("  - name: translate_sim")[0])  # braille only
    first = _fit(recipe, tmp_path / "run")
    again = _fit(recipe, tmp_path / "run")
    assert (
        again["stages"][0]["cached"]
        and again["stages"][0]["directory"] == (first["stages"][0]["directory"])
    )
    profile = tmp_path / "unit.yaml"
    profile.write_text(profile.read_text().replace("name: digit", "name: digit_edited"))
    edited = _fit(recipe, tmp_path / "run")
    assert not edited["stages"][0]["cached"]
    assert edited["stages"][0]["directory"] != first["stages"][0]["directory"]


def test_a_relative_profile_path_is_read_beside_the_recipe(
    recipe: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    braille_only = recipe.read_text().split("  - name: translate_sim")[0]
    recipe.write_text(braille_only.replace(str(tmp_path / "unit.yaml"), "unit.yaml"))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the profile is not in the working directory
    run = _fit(recipe, tmp_path / "run")
    assert run["stages"][0]["config"]["real_sensor"] == "unit.yaml"


def test_network_stages_are_keyed_by_what_auto_resolves_to(
    recipe: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another machine where auto means bf16 must not reuse this one's fp32 classifiers,
    while data stages stay shared across machines."""
    loaded = load_recipe(recipe)
    keys = {}
    for native in (False, True):
        monkeypatch.setattr(hardware, "native_bf16", lambda device="cpu", n=native: n)
        keys[native] = {stage.name: stage_key(loaded, stage, {}) for stage in loaded.stages}
    assert keys[False]["braille"] == keys[True]["braille"]
    assert keys[False]["report"] == keys[True]["report"]
    assert keys[False]["classify_sim"] != keys[True]["classify_sim"]
    assert keys[False]["translate_sim"] != keys[True]["translate_sim"]
    kinds = {stage.name: stage.kind for stage in loaded.stages}
    assert not kinds["braille"].precision_dependent and kinds["classify_sim"].precision_dependent
