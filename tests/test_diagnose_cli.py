"""``diagnose`` and ``export-pairs`` end to end, in-process, and the recipe stage ``diagnose``.

The command runs the real diagnosis with a single cheap candidate; ``run.Steps`` takes a
stand-in (a fitted per-channel offset) to check the report's plumbing against a known answer.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet
from tactile_bench.diagnose.commands import summary_lines
from tactile_bench.diagnose.no_contact import CONFIRMS, NO_SIM_FRAME, FrameReading
from tactile_bench.diagnose.paired import DiagnosisPairs, load_paired, write_paired
from tactile_bench.diagnose.ranking import EffectFit
from tactile_bench.diagnose.result import Diagnosis, Split
from tactile_bench.diagnose.run import Steps, diagnose, stratified_split
from tactile_bench.diagnose.shrink import Downstream, HowFar, KidScores, Skipped
from tactile_bench.diagnose.stability import Stability
from tactile_bench.diagnose.where import WhereResult
from tactile_bench.diagnose.which import WhichResult
from tactile_bench.geometry.contacts import Poses
from tests.test_diagnose_paired import tiny_pairs

CANDIDATES = ["vignetting"]


@pytest.fixture
def backend(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The candidate list to pass, and a few encoder steps: the tests check the plumbing."""
    monkeypatch.setattr("tactile_bench.diagnose.shrink.ENCODER_STEPS", 10)
    return CANDIDATES


# ------------------------------------------------------------------ a stand-in for the steps
def _offset(data: DiagnosisPairs, idx: torch.Tensor) -> torch.Tensor:
    return (data.real[idx] - data.sim[idx]).mean((0, 2, 3))


def _apply(data: DiagnosisPairs, effects: dict, idx: torch.Tensor | None = None, *_: object):
    sim = data.sim if idx is None else data.sim[idx]
    if "offset" in effects:
        p = effects["offset"]
        sim = sim + torch.tensor([p["r"], p["g"], p["b"]]).view(1, 3, 1, 1)
    return sim


def _held_mse(data: DiagnosisPairs, held_idx: torch.Tensor, effects: dict) -> float:
    return float((data.real[held_idx] - _apply(data, effects, held_idx)).square().mean())


def _explain(data, fit_idx, held_idx, candidates=None, seed=0, progress=True) -> WhichResult:
    r, g, b = _offset(data, fit_idx).tolist()
    effects = {"offset": {"r": r, "g": g, "b": b}}
    before, after = _held_mse(data, held_idx, {}), _held_mse(data, held_idx, effects)
    shrink = (before - after) / before
    fit = EffectFit("offset", effects["offset"], before, after, shrink, shrink - 0.01, shrink)
    unexplained = after / before
    return WhichResult([fit], [fit], unexplained, unexplained > 0.5, "pixel MSE (stand-in)")


def _how_far(data, fit_idx, held_idx, effects, downstream=True, seed=0, progress=True) -> HowFar:
    before = {"mse": _held_mse(data, held_idx, {})}
    after = {"mse": _held_mse(data, held_idx, effects)}
    return HowFar(effects, before, after, Skipped("stand-in"), Skipped("--no-downstream"))


def test_the_report_holds_what_the_steps_found(tmp_path: Path) -> None:
    data = tiny_pairs(n=12)
    steps = Steps(explain_gap=_explain, how_far=_how_far, apply_effects=_apply)
    result = diagnose(data, tmp_path / "out", steps=steps, progress=False)
    assert result.which.ranking[0].effect == "offset" and result.which.unexplained < 0.01
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["ranking"][0]["effect"] == "offset" and report["unexplained"] < 0.01
    assert report["how_far"]["pixel"]["after"]["mse"] < report["how_far"]["pixel"]["before"]["mse"]
    assert report["downstream"] == {"skipped": "--no-downstream"}
    text = "\n".join(summary_lines(result))
    assert "offset" in text and "downstream: skipped (--no-downstream)" in text


# ------------------------------------------------------------------ diagnose
def test_diagnose_no_downstream_writes_both_files(
    tmp_path: Path, backend: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    root = write_paired(tmp_path / "pairs", tiny_pairs(n=12))
    out = tmp_path / "out"
    args = ["diagnose", str(root), "--out", str(out), "--no-downstream", "--no-progress"]
    args += ["--candidates", *backend]
    assert main(args) == 0
    stdout = capsys.readouterr().out
    assert "where the gap lies" in stdout and str(out / "report.html") in stdout
    report = json.loads((out / "report.json").read_text())
    for key in ("n_pairs", "where", "ranking", "singles", "unexplained", "residual_flagged"):
        assert key in report
    assert report["n_pairs"] == 12 and report["split"]["n_fit"] + report["split"]["n_held"] == 12
    assert report["input"]["layout"] == "paired" and len(report["input"]["hash"]) == 64
    assert report["how_far"]["downstream"] == report["downstream"]
    assert "skipped" in report["downstream"]
    assert report["timing_s"]["total"] > 0
    for row in report["ranking"] + report["singles"]:
        assert set(row) >= {"effect", "params", "gap_before", "gap_after", "shrink"}
        assert set(row) >= {"ci_low", "ci_high"}
    # real = sim + 10 everywhere: the uniform offset dominates where the gap lies
    assert report["where"]["axes"]["band"][0]["part"] == "DC (uniform offset)"
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 5  # maps, shares, spectrum, shrinks, samples
    assert 'src="http' not in page and "<table>" in page


def test_diagnose_bad_input_names_the_file(
    tmp_path: Path, backend: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    root = write_paired(tmp_path / "pairs", tiny_pairs(n=6))
    victim = root / "sim" / "A" / "p03.png"
    victim.unlink()
    assert main(["diagnose", str(root), "--out", str(tmp_path / "o")]) == 2
    assert str(victim) in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    assert main(["diagnose", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
    args = ["diagnose", str(root), "--out", str(tmp_path / "o"), "--candidates", "warp_drive"]
    assert main(args) == 2
    assert "warp_drive" in capsys.readouterr().err


def test_stratified_split() -> None:
    labels = ["a"] * 10 + ["b"] * 7 + ["c"] * 1
    fit, held = stratified_split(labels, 0.5, seed=3)
    assert sorted(fit.tolist() + held.tolist()) == list(range(18))
    assert sum(labels[i] == "a" for i in fit) == 5
    assert abs(sum(labels[i] == "b" for i in fit) - 3.5) == 0.5
    assert abs(len(fit) - 9) <= 1
    again, _ = stratified_split(labels, 0.5, seed=3)
    assert torch.equal(fit, again)
    with pytest.raises(Exception, match="at least"):
        stratified_split(["a", "b"], 0.5)


# ------------------------------------------------------------------ export-pairs
def test_export_pairs_generate_round_trip(tmp_path: Path) -> None:
    out = tmp_path / "gen"
    args = ["export-pairs", "--generate", "6", "--chars", "A#", "--size", "32", "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    data = load_paired(out)
    assert len(data) == 6 and data.size == 32
    assert sorted(data.labels) == ["#"] * 3 + ["A"] * 3
    assert (out / "depth" / "number_sign").is_dir() and data.sim_background is not None
    assert float(data.depth.max()) > 0.2  # the presses reach the gel
    assert float((data.real - data.sim).abs().mean()) > 1  # "real" differs from sim
    assert main([*args, "--no-progress"]) == 2  # refuses to overwrite
    assert main([*args, "--no-progress", "--overwrite", "--noise-free-sim"]) == 0
    assert main(["export-pairs", "--out", str(tmp_path / "x")]) == 2  # no source at all


def _braille_set(n: int = 6, size: int = 16) -> BrailleSet:
    labels = torch.arange(n) % 3
    poses = Poses(labels, torch.zeros(n), torch.zeros(n), torch.zeros(n), torch.full((n,), 0.5))
    g = torch.Generator().manual_seed(0)
    images = torch.randint(0, 256, (2, n, 3, size, size), generator=g, dtype=torch.uint8)
    bg = torch.full((3, size, size), 90, dtype=torch.uint8)
    depth = torch.rand(n, 1, size, size, generator=g)
    return BrailleSet(depth, images[0], images[1], labels, poses, bg, bg + 10)


def test_export_pairs_from_a_stage_and_a_run(tmp_path: Path) -> None:
    stage = tmp_path / "run" / "braille-0123abcd"
    stage.mkdir(parents=True)
    bset = _braille_set()
    bset.save(stage / "test.npz")
    (stage / "_done.json").write_text(json.dumps({"config": {"chars": "AB#"}}))
    for source in (stage, tmp_path / "run", stage / "test.npz"):
        out = tmp_path / f"out_{source.name}"
        assert main(["export-pairs", str(source), "--set", "test", "--out", str(out)]) == 0
        data = load_paired(out)
        assert sorted(data.labels) == ["#", "#", "A", "A", "B", "B"]
        i = data.names.index("00002")  # pair 2 has label 2 = '#'
        assert data.labels[i] == "#"
        assert torch.equal(data.real[i], bset.real[2].float())
        assert torch.equal(data.background, bset.real_background.float())
    assert main(["export-pairs", str(tmp_path / "run"), "--set", "finetune", "--out", "y"]) == 2


# ------------------------------------------------------------------ the recipe stage
def test_diagnose_stage(tmp_path: Path, backend: list[str]) -> None:
    from tactile_bench.pipeline.stages import STAGES
    from tactile_bench.pipeline.stages.base import StageContext, StageResult

    kind = STAGES["diagnose"]
    with pytest.raises(Exception, match="set"):
        kind.check(kind.config_model(set="nope"), tmp_path)
    upstream = tmp_path / "braille-x"
    upstream.mkdir()
    _braille_set(n=12).save(upstream / "test.npz")
    (upstream / "_done.json").write_text(json.dumps({"config": {"chars": "XYZ"}}))
    result = StageResult("braille", "braille_data", upstream, {"test": "test.npz"}, {}, "h", 0.0)
    config = kind.config_model(downstream=False, candidates=backend)
    kind.check(config, tmp_path)
    directory = tmp_path / "diag"
    directory.mkdir()
    ctx = StageContext("diag", directory, config, {"data": [result]}, 0, {}, tmp_path)
    ctx.progress = False
    outputs, metrics = kind.run(ctx)
    assert (directory / outputs["report_json"]).is_file()
    assert (directory / outputs["report_html"]).is_file()
    report = json.loads((directory / "report.json").read_text())
    assert report["n_pairs"] == 12 and sorted(set(s["label"] for s in report["samples"])) <= [
        "X",
        "Y",
        "Z",
    ]
    assert metrics["n_pairs"] == 12
    assert metrics["compute_precision"] is None  # downstream=False: no classifiers trained
    assert kind.precision_dependent  # with downstream classifiers its result depends on it


def _diagnosis(how_far: HowFar | None = None, **which: object) -> Diagnosis:
    """A diagnosis of 8 pairs with the "which" fields ``which`` (a plain one by default)."""
    fields = {"ranking": [], "singles": [], "unexplained": 0.0, "residual_flagged": False}
    where = WhereResult({"mse": 3.0, "dominant": []})
    pixel = {"mse": 9.0, "ssim": 0.5}, {"mse": 4.0, "ssim": 0.7}
    return Diagnosis(
        n_pairs=8,
        size=16,
        input={},
        split=Split(4, 4, 0.5, 0),
        where=where,
        where_held=None,
        which=WhichResult(**(fields | which), gap_metric="g"),  # type: ignore[arg-type]
        how_far=how_far or HowFar({}, *pixel, Skipped("x"), Skipped("--no-downstream")),
        samples=[],
        timing_s={"total": 1.0},
    )


def test_summary_lines_read_every_how_far_part() -> None:
    kid = KidScores(0.1, 0.05, 0.01, 0.01, "enc")
    down = Downstream(3, 6, 6, 2, "tiny", {}, 0.3, 0.6, 0.9)
    far = HowFar({}, {"mse": 9.0, "ssim": 0.5}, {"mse": 4.0, "ssim": 0.7}, kid, down)
    result = _diagnosis(far, unexplained=1.0, residual_flagged=True)
    result.where.summary["dominant"] = [{"axis": "band", "part": "DC", "share": 0.5}]
    text = "\n".join(summary_lines(result))
    assert "mse 9 -> 4" in text and "KID 0.1 -> 0.05" in text and "real 0.9" in text
    assert "no candidate" in text and "band" in text


def test_the_summary_warns_when_the_depth_split_names_another_effect() -> None:
    accepted = ["optical_response", "elastic_spread"]
    stability = Stability("led_diffusivity", False, 50, 50, 0.9, 1.1, accepted)
    text = "\n".join(summary_lines(_diagnosis(unexplained=0.02, stability=stability)))
    assert "names led_diffusivity first" in text and "outside the candidates" in text
    assert "no candidate explains" not in text  # the residual itself is small
    agreeing = Stability("led_diffusivity", True, 50, 50, 0.9, 1.1, accepted)
    assert "names led_diffusivity" not in "\n".join(summary_lines(_diagnosis(stability=agreeing)))


def test_first_lines_show_the_background_line_sim_optics_and_confusable_sets() -> None:
    fit = EffectFit("vignetting", {}, 2.0, 0.8, 0.6, 0.5, 0.7, ["optical_response"], "a press")
    optics = {"model": "fitted lookup", "builtin_mse": 9.0, "lookup_mse": 1.0}
    background = EffectFit("measured_background", {}, 1.0, 0.58, 0.42, 0.4, 0.44)
    result = _diagnosis(ranking=[fit], background=background, sim_optics=optics)
    lines = summary_lines(result)
    assert lines[1].startswith("background:") and "0.420 [0.400, 0.440]" in lines[1]
    assert lines[2].startswith("sim optics for geometry effects: fitted lookup")
    assert lines[3] == (
        "confusable: vignetting ~ optical_response (the data at hand cannot tell them apart)"
    )
    composited = _diagnosis(ranking=[fit], background_note="the sim was composited")
    assert summary_lines(composited)[1] == "background: the sim was composited"


def test_the_ranking_shows_what_the_no_contact_frame_says_of_a_lens() -> None:
    reading = FrameReading(CONFIRMS, 5.8, 0.3, 0.95, 4.8, 6.1, 3.8, 0.07)
    fit = EffectFit("defocus_blur", {"sigma_mm": 0.2}, 2.0, 0.8, 0.6, 0.5, 0.7, no_contact=reading)
    text = "\n".join(summary_lines(_diagnosis(ranking=[fit])))
    assert "no-contact frame: confirms (texture gap 5.8 -> 0.3 grey level^2" in text
    unread = dataclasses.replace(fit, no_contact=FrameReading(NO_SIM_FRAME))
    assert "no-contact frame: no sim no-contact frame" in "\n".join(
        summary_lines(_diagnosis(ranking=[unread]))
    )


def test_the_summary_says_unexplained_is_counted_above_the_pairs_noise() -> None:
    noise = {"sim": [0.0, 0.0, 0.0], "real": [2.1, 2.4, 2.2]}
    text = "\n".join(summary_lines(_diagnosis(noise=noise)))
    assert "counted above the pairs' own noise (std, grey levels: sim 0, real 2.4)" in text
