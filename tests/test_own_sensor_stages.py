"""The own-sensor chain in a recipe: paired_data -> calibrate -> the profile as a translator
-> compare_translators -> sensor_report, and a corpus rendered by the calibrated profile."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.data.corpus import load_pairs
from tactile_bench.diagnose.paired import write_paired
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.pipeline.runner import read_done
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit

SIZE = 24

CHAIN = """
name: own
seed: 0
stages:
  - {name: pairs, kind: paired_data, config: {source: pairs}}
  - name: diagnose
    kind: diagnose
    inputs: {data: pairs}
    config: {set: all, downstream: false, candidates: [optical_response]}
  - name: calibrate
    kind: calibrate
    inputs: {data: pairs}
    config: {candidates: [optical_response]}
  - {name: tr_sim, kind: translate, inputs: {data: pairs}, config: {translator: sim, sets: [test]}}
  - name: tr_profile
    kind: translate
    inputs: {data: pairs, translator: calibrate}
    config: {sets: [test]}
  - name: compare
    kind: compare_translators
    inputs: {data: pairs, translated: [tr_sim, tr_profile]}
    config: {encoder_steps: 3, samples: 2}
  - name: report
    kind: sensor_report
    inputs: {calibration: calibrate, diagnosis: diagnose, similarity: compare}
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 braille pairs whose 'real' sensor answers light with the GelSight's response."""
    bank = build_bank(("A", "L"), BrailleSpec())
    data = planted_pairs(bank, {"optical_response": {}}, 16, 3, SIZE)
    return write_paired(tmp_path_factory.mktemp("own") / "pairs", data)


def _run(tmp_path: Path, recipe: str, folder: Path) -> tuple[int, Path]:
    (tmp_path / "pairs").symlink_to(folder, target_is_directory=True)
    (tmp_path / "own.yaml").write_text(recipe)
    run_dir = tmp_path / "run"
    return main(["fit", str(tmp_path / "own.yaml"), "--run-dir", str(run_dir), "--no-progress"]), (
        run_dir
    )


def _stage(run_dir: Path, name: str) -> Path:
    run = json.loads((run_dir / "run.json").read_text())
    return run_dir / next(s["directory"] for s in run["stages"] if s["name"] == name)


def test_the_calibrated_profile_is_compared_beside_the_sim_and_reported(
    tmp_path: Path, folder: Path
) -> None:
    code, run_dir = _run(tmp_path, CHAIN, folder)
    assert code == 0
    calibrate = read_done(_stage(run_dir, "calibrate"))
    pairs = read_done(_stage(run_dir, "pairs"))
    assert calibrate is not None and pairs is not None
    # the profile is fitted on the data stage's fit share, scored on its held-out share
    assert calibrate.metrics["n_fit"] == pairs.metrics["n_fit"]
    held = calibrate.metrics["heldout"]
    assert held["profile"]["contact_mse"] < held["sim"]["contact_mse"]
    SurrogateDigit.from_profile(calibrate.path("profile"))  # loads where a profile is taken
    rows = json.loads((_stage(run_dir, "compare") / "similarity.json").read_text())["rows"]
    by_name = {r["translator"]: r for r in rows}
    assert set(by_name) == {"sim", "profile"}
    assert by_name["profile"]["mse"] < by_name["sim"]["mse"]
    report = (run_dir / "report.md").read_text()
    for heading in ("The calibrated profile", "The gap diagnosis", "Translators on the held-out"):
        assert heading in report
    assert "| profile | tr_profile |" in report and (run_dir / "report.html").is_file()


def test_calibrate_refuses_a_stage_that_is_not_paired_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recipe = """
name: wrong
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 8, n_test: 8, n_classifier: 8, n_classifier_test: 8}
  - {name: calibrate, kind: calibrate, inputs: {data: braille}}
"""
    (tmp_path / "wrong.yaml").write_text(recipe)
    code = main(["fit", str(tmp_path / "wrong.yaml"), "--run-dir", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "calibrate reads a paired_data stage" in err[-1]


def test_a_corpus_rendered_by_the_calibrated_profile_has_its_no_contact_frame(
    tmp_path: Path, folder: Path
) -> None:
    recipe = """
name: corpus
seed: 0
stages:
  - {name: pairs, kind: paired_data, config: {source: pairs}}
  - {name: calibrate, kind: calibrate, inputs: {data: pairs}, config: {candidates: [vignetting]}}
  - name: corpus
    kind: ycb_slide_data
    inputs: {sensor: calibrate}
    config: {n_pairs: 12, objects: [006_mustard_bottle], image_size: 16}
"""
    code, run_dir = _run(tmp_path, recipe, folder)
    assert code == 0
    profile = SurrogateDigit.from_profile(read_done(_stage(run_dir, "calibrate")).path("profile"))
    corpus = load_pairs(_stage(run_dir, "corpus"), "all")
    want = profile.background(profile.gel(16))
    assert torch.allclose(corpus.real_background[0].float(), want, atol=1.0)
