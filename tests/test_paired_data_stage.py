"""Stage ``paired_data`` (a user's own paired folder in a recipe) and the ``profile``
translator: the split, the chain to translators, classifiers and the diagnosis, bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
import torch
import torch.nn.functional as F

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet
from tactile_bench.diagnose.paired import DiagnosisPairs, load_paired, write_paired
from tactile_bench.diagnose.run import stratified_split
from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.runner import read_done
from tactile_bench.pipeline.stages.paired_data import share_folder
from tactile_bench.sensor.press_grounding import sim_render
from tactile_bench.sensor.surrogate import PROFILE_DIR, SurrogateDigit
from tactile_bench.testing import TranslatorContract
from tactile_bench.translators import create_translator

LABELS = ("dot", "ridge")  # not braille characters: the stage's labels are the folder's
N, SIZE = 16, 24  # the KID encoder needs a side divisible by 8


def _dents(n: int, size: int, seed: int = 0) -> torch.Tensor:
    """(n, 1, size, size) mm: one round dent each, up to 0.6 mm deep."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    depth = torch.zeros(n, 1, size, size)
    for i in range(n):
        cy, cx = torch.randint(5, size - 5, (2,), generator=g).tolist()
        depth[i, 0] = (0.6 - ((yy - cy) ** 2 + (xx - cx) ** 2).float() / 30).clamp(min=0)
    return depth


def _pairs(n: int = N, size: int = SIZE) -> DiagnosisPairs:
    """Pairs a surrogate DIGIT renders ("real") beside the plain simulator on its frame."""
    unit = SurrogateDigit.from_profile("digit")
    gel = unit.gel(size, 1)
    depth = _dents(n, size)
    real = unit.render_surface(depth, gel, torch.Generator().manual_seed(1)).round()
    background = unit.background(gel).round()
    sim = sim_render(depth, background, gel).round().clamp(0, 255)
    labels = [LABELS[i % 2] for i in range(n)]
    return DiagnosisPairs(
        depth, sim, real, background, None, labels, [f"p{i:02d}" for i in range(n)]
    )


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 labelled pairs at 24 x 24 with sim/."""
    return write_paired(tmp_path_factory.mktemp("paired") / "pairs", _pairs())


@pytest.fixture(scope="module")
def portrait(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 pairs in a DIGIT-like portrait frame (24 wide, 32 high) over a 15 x 20 mm gel
    (gel.json), without sim/."""
    data = _pairs(size=24)

    def tall(x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x, size=(32, 24), mode="bilinear", align_corners=False)

    data = DiagnosisPairs(
        tall(data.depth),
        tall(data.sim).round(),
        tall(data.real).round(),
        tall(data.background[None])[0].round(),
        None,
        data.labels,
        data.names,
        gel_mm=(15.0, 20.0),
    )
    root = write_paired(tmp_path_factory.mktemp("portrait") / "pairs", data)
    shutil.rmtree(root / "sim")
    return root


def _run(tmp_path: Path, recipe: str, name: str = "r") -> tuple[int, dict[str, Path]]:
    path = tmp_path / f"{name}.yaml"
    path.write_text(recipe)
    run_dir = tmp_path / f"run_{name}"
    code = main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"])
    if code != 0:
        return code, {}
    run = json.loads((run_dir / "run.json").read_text())
    return code, {s["name"]: run_dir / s["directory"] for s in run["stages"]}


def _metrics(directory: Path) -> dict[str, Any]:
    return json.loads((directory / "_done.json").read_text())["metrics"]


def _keys(data: DiagnosisPairs, idx: torch.Tensor) -> list[str]:
    return [f"{data.labels[i]}/{data.names[i]}" for i in idx.tolist()]


# ------------------------------------------------------------------ the split
def test_the_split_is_stratified_split_s_and_seeded(tmp_path: Path, folder: Path) -> None:
    stage = "stages:\n  - {name: p, kind: paired_data, config: {source: %s, holdout: 0.25}}\n"
    splits, stages = [], []
    for i, seed in enumerate((5, 5, 6)):
        code, dirs = _run(tmp_path, f"name: s{i}\nseed: {seed}\n" + stage % folder, f"s{i}")
        assert code == 0
        stages.append(dirs["p"])
        splits.append(json.loads((dirs["p"] / "split.json").read_text()))
    assert splits[0] == splits[1] and splits[0]["fit"] != splits[2]["fit"]
    data = load_paired(folder)
    fit, held = stratified_split(data.labels, 0.75, 5)
    assert splits[0]["fit"] == _keys(data, fit) and splits[0]["heldout"] == _keys(data, held)
    assert splits[0]["seed"] == 5 and splits[0]["holdout"] == 0.25
    metrics = _metrics(stages[0])
    assert (metrics["n_pairs"], metrics["labels"], metrics["classes"]) == (N, 2, list(LABELS))
    assert metrics["n_fit"] == 12 and metrics["n_heldout"] == 4 and metrics["sim"] == "folder"
    # the shares as paired folders, and as braille sets under the names consumers read
    result = read_done(stages[0])
    assert result is not None
    back = load_paired(share_folder(result, "fit"))
    assert sorted(f"{a}/{b}" for a, b in zip(back.labels, back.names, strict=True)) == sorted(
        splits[0]["fit"]
    )
    test = BrailleSet.load(stages[0] / "heldout.npz")
    want = [LABELS.index(key.split("/")[0]) for key in splits[0]["heldout"]]
    assert len(test) == 4 and test.labels.tolist() == want
    torch.testing.assert_close(test.real.float(), data.real[held])


# ------------------------------------------------------------------ chains
CHAIN = """
name: chain
seed: 2
stages:
  - name: paired
    kind: paired_data
    config: {source: pairs}
  - name: fit_cm
    kind: fit_translator
    inputs: {braille: paired}
    config:
      translator: colour_match
      fraction: 0.5
      translator_config: {max_steps: 3, batch_size: 4}
  - name: fit_profile
    kind: fit_translator
    inputs: {braille: paired}
    config: {translator: profile, translator_config: {profile: cal.yaml, gel_mm: [15, 20]}}
  - name: tr_cm
    kind: translate
    inputs: {data: paired, translator: fit_cm}
    config: {sets: [test]}
  - name: tr_profile
    kind: translate
    inputs: {data: paired, translator: fit_profile}
    config: {sets: [test]}
  - name: compare
    kind: compare_translators
    inputs: {data: paired, translated: [tr_cm, tr_profile]}
    config: {encoder_steps: 3, samples: 4}
"""
CALIBRATED = "name: cal\nunit: digit\neffects:\n  vignetting: {}\n  camera_noise: {}\n"


def test_a_portrait_folder_without_sim_feeds_translators_and_their_comparison(
    tmp_path: Path, portrait: Path
) -> None:
    shutil.copytree(portrait, tmp_path / "pairs")  # relative to the recipe, not the cwd
    (tmp_path / "cal.yaml").write_text(CALIBRATED)
    code, dirs = _run(tmp_path, CHAIN)
    assert code == 0
    paired = _metrics(dirs["paired"])
    assert paired["size"] == 24 and paired["gel_mm"] == [15.0, 20.0]  # min(64, 24); gel.json
    assert paired["sim"] == "rendered" and paired["sim_background_given"] is False
    assert paired["n_fit"] + paired["n_heldout"] == N
    fit = BrailleSet.load(dirs["paired"] / "fit.npz")
    assert tuple(fit.depth.shape[1:]) == (1, 24, 24) and tuple(fit.sim.shape[1:]) == (3, 24, 24)
    # the rendered sim: the plain simulator over the folder's own no-contact frame
    assert torch.equal(fit.sim_background, fit.real_background)
    cm = json.loads((dirs["fit_cm"] / "metrics.json").read_text())
    assert cm["fit_pairs"] == paired["n_fit"] // 2 and 0 < cm["heldout"]["ssim"] <= 1
    profile = json.loads((dirs["fit_profile"] / "metrics.json").read_text())
    assert profile["fit_pairs"] == paired["n_fit"] and set(profile["fit"]) == {"profile", "effects"}
    assert profile["fit"]["effects"] == ["vignetting", "camera_noise"]
    rows = json.loads((dirs["compare"] / "similarity.json").read_text())["rows"]
    assert [r["translator"] for r in rows] == ["colour_match", "profile"]
    assert all(0 < r["ssim"] <= 1 and r["mse"] > 0 for r in rows)


CLASSIFY = """
name: classify
stages:
  - {name: paired, kind: paired_data, config: {source: %s}}
  - name: tr_sim
    kind: translate
    inputs: {data: paired}
    config: {translator: sim}
  - name: cls
    kind: classify
    inputs: {data: paired, images: tr_sim}
    config: {row: sim, classifier: {width: 4, blocks: [1, 1, 1, 1], epochs: 1}}
"""


def test_classify_trains_on_the_fit_share_and_tests_on_the_held_out(
    tmp_path: Path, folder: Path
) -> None:
    code, dirs = _run(tmp_path, CLASSIFY % folder)
    assert code == 0
    paired = _metrics(dirs["paired"])
    scores = json.loads((dirs["cls"] / "metrics.json").read_text())
    summary = scores["summary"]
    assert len(scores["per_seed"][0]["test"]["confusion"]) == len(LABELS)  # the folder's labels
    # trained on the fit share's sim images, tested on the held-out share's real frames
    assert summary["n_test"] == paired["n_heldout"] and summary["tested_on"] == "real"
    assert 0 <= summary["accuracy"]["mean"] <= 1 and summary["test_sim_accuracy"] is not None


DIAGNOSE = """
name: diagnose
stages:
  - {name: paired, kind: paired_data, config: {source: %s}}
  - name: diag
    kind: diagnose
    inputs: {data: paired}
    config: {set: all, downstream: false, candidates: [vignetting]}
"""


def test_diagnose_reads_the_stage_s_labels_and_split(
    tmp_path: Path, folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("tactile_bench.diagnose.shrink.ENCODER_STEPS", 10)
    code, dirs = _run(tmp_path, DIAGNOSE % folder)
    assert code == 0
    paired = _metrics(dirs["paired"])
    report = json.loads((dirs["diag"] / "report.json").read_text())
    assert report["n_pairs"] == N and report["input"]["layout"] == "paired_data"
    assert report["split"]["n_held"] == paired["n_heldout"]  # 1 - holdout: the stage's split
    assert report["background_note"].startswith("the sim was composited onto the measured")
    assert {sample["label"] for sample in report["samples"]} <= set(LABELS)


# ------------------------------------------------------------------ bad input
def _bad(case: str, root: Path) -> Path:
    """A copy of a good folder with one thing wrong; returns the file the error must name."""
    if case == "missing":
        shutil.rmtree(root)
        return root
    if case == "few":
        for path in sorted((root / "depth").rglob("*.png"))[3:]:
            for part in ("depth", "sim", "real"):
                (root / part / path.relative_to(root / "depth")).unlink()
        return root
    from PIL import Image

    if case == "mixed":
        path = root / "real" / LABELS[1] / "p03.png"
        Image.open(path).resize((SIZE + 4, SIZE + 4)).save(path)
        return path
    path = root / "background.png"
    Image.open(path).resize((SIZE * 2, SIZE * 2)).save(path)
    return path


@pytest.mark.parametrize("case", ["missing", "few", "mixed", "background"])
def test_bad_folders_are_one_line_naming_the_file(
    tmp_path: Path, folder: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    root = shutil.copytree(folder, tmp_path / "pairs")
    named = _bad(case, root)
    recipe = "name: bad\nstages:\n  - {name: p, kind: paired_data, config: {source: pairs}}\n"
    code, _ = _run(tmp_path, recipe)
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(errors) == 1  # the other lines are the runner's log
    assert str(named) in errors[0]
    if case == "few":
        assert "3 pair(s); paired_data needs at least 4" in errors[0]


def test_a_missing_profile_is_refused_before_any_stage_runs(
    tmp_path: Path, folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copytree(folder, tmp_path / "pairs")
    code, _ = _run(tmp_path, CHAIN)  # no cal.yaml beside the recipe
    err = capsys.readouterr().err
    assert code == 2 and "translator: translator 'profile'" in err
    assert str(tmp_path / "cal.yaml") in err
    assert not list(tmp_path.glob("run_r/*/_done.json"))  # refused when the recipe loads


def test_list_stages_shows_it(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list", "stages"]) == 0
    assert "  paired_data    your own sensor's paired folder" in capsys.readouterr().out


# ------------------------------------------------------------------ the profile translator
class TestProfileContract(TranslatorContract):
    name = "profile"
    tiny_config = {"profile": str(PROFILE_DIR / "digit.yaml")}  # a path: names are refused


def test_a_built_in_profile_name_is_refused_as_a_translator() -> None:
    with pytest.raises(TactileBenchError) as info:
        create_translator("profile", {"profile": "digit"})
    assert "built-in surrogate profile" in str(info.value) and "\n" not in str(info.value)


def test_profile_renders_the_profile_on_the_given_frame(tmp_path: Path) -> None:
    (tmp_path / "cal.yaml").write_text(CALIBRATED)
    translator = create_translator("profile", {"profile": str(tmp_path / "cal.yaml")})
    depth, background = _dents(3, 24), torch.full((3, 24, 24), 90.0)
    image = translator.translate(depth, background, torch.Generator().manual_seed(4))
    sensor = SurrogateDigit.from_profile(tmp_path / "cal.yaml")
    gel = sensor.gel(24, 1)
    rendered = sensor.render_surface(depth, gel, torch.Generator().manual_seed(4))
    want = (rendered - sensor.background(gel) + background).clamp(0, 255)
    torch.testing.assert_close(image, want, atol=1e-3, rtol=0)
    assert translator.fit_pairs(depth, depth.expand(-1, 3, -1, -1), tmp_path) is None


def test_a_profile_that_does_not_load_is_one_line_naming_the_key() -> None:
    with pytest.raises(TactileBenchError) as info:
        create_translator("profile", {"profile": "no/such.yaml"})
    assert "config key 'profile'" in str(info.value) and "\n" not in str(info.value)
