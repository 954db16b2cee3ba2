"""``diagnose`` and ``export-pairs`` end to end, in-process, and the recipe stage ``diagnose``.

While the "which"/"how far" modules are absent, a small stand-in (a fitted per-channel offset)
takes their place; once ``tactile_bench.diagnose.which`` exists the real one runs with a
single cheap candidate.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys
import types
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet
from tactile_bench.diagnose.paired import PairedData, load_paired, write_paired
from tactile_bench.diagnose.run import stratified_split
from tactile_bench.geometry.contacts import Poses
from tests.test_diagnose_paired import tiny_pairs

REAL_BACKEND = importlib.util.find_spec("tactile_bench.diagnose.which") is not None
REAL_SHRINK = importlib.util.find_spec("tactile_bench.diagnose.shrink") is not None
CANDIDATES = ["vignetting"]


# ------------------------------------------------------------------ stand-in for which/shrink
@dataclass
class _Fit:
    effect: str
    params: dict[str, float]
    gap_before: float
    gap_after: float
    shrink: float
    ci_low: float
    ci_high: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Which:
    ranking: list[_Fit]
    singles: list[_Fit]
    unexplained: float
    residual_flagged: bool
    gap_metric: str = "pixel MSE (stand-in)"

    @property
    def flagged(self) -> bool:
        return self.residual_flagged

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "ranking": [asdict(f) for f in self.ranking]}


def _offset(data: PairedData, idx: torch.Tensor) -> torch.Tensor:
    return (data.real[idx] - data.sim[idx]).mean((0, 2, 3))


def _apply(data: PairedData, effects: dict, idx: torch.Tensor | None = None, seed: int = 0):
    sim = data.sim if idx is None else data.sim[idx]
    if "offset" in effects:
        p = effects["offset"]
        sim = sim + torch.tensor([p["r"], p["g"], p["b"]]).view(1, 3, 1, 1)
    return sim


def _explain(data, fit_idx, held_idx, candidates=None, seed=0, progress=True) -> _Which:
    r, g, b = _offset(data, fit_idx).tolist()
    effects = {"offset": {"r": r, "g": g, "b": b}}
    before = float((data.real[held_idx] - data.sim[held_idx]).square().mean())
    after = float((data.real[held_idx] - _apply(data, effects, held_idx)).square().mean())
    shrink = (before - after) / before
    fit = _Fit("offset", effects["offset"], before, after, shrink, shrink - 0.01, shrink + 0.01)
    return _Which([fit] if shrink > 0 else [], [fit], after / before, after / before > 0.5)


def _how_far(data, fit_idx, held_idx, effects, downstream=True, seed=0, progress=True):
    before = float((data.real[held_idx] - data.sim[held_idx]).square().mean())
    after = float((data.real[held_idx] - _apply(data, effects, held_idx)).square().mean())
    down = {"skipped": "--no-downstream"} if not downstream else {"real_accuracy": 1.0}
    return {"pixel": {"before": {"mse": before}, "after": {"mse": after}}, "downstream": down}


@pytest.fixture
def backend(monkeypatch: pytest.MonkeyPatch) -> list[str] | None:
    """The candidate list to pass: the real module's cheap one, or None with the stand-in."""
    if REAL_SHRINK:  # a few encoder steps: the test checks the plumbing, not the KID
        shrink_mod = importlib.import_module("tactile_bench.diagnose.shrink")
        monkeypatch.setattr(shrink_mod, "ENCODER_STEPS", 10, raising=False)
    else:
        shrink = types.ModuleType("tactile_bench.diagnose.shrink")
        shrink.how_far = _how_far
        monkeypatch.setitem(sys.modules, "tactile_bench.diagnose.shrink", shrink)
    if REAL_BACKEND:
        return CANDIDATES
    which = types.ModuleType("tactile_bench.diagnose.which")
    which.explain_gap, which.apply_effects = _explain, _apply
    monkeypatch.setitem(sys.modules, "tactile_bench.diagnose.which", which)
    return None


# ------------------------------------------------------------------ diagnose
def test_diagnose_no_downstream_writes_both_files(
    tmp_path: Path, backend: list[str] | None, capsys: pytest.CaptureFixture[str]
) -> None:
    root = write_paired(tmp_path / "pairs", tiny_pairs(n=12))
    out = tmp_path / "out"
    args = ["diagnose", str(root), "--out", str(out), "--no-downstream", "--no-progress"]
    args += ["--candidates", *backend] if backend else []
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
    if not REAL_BACKEND:
        assert report["ranking"][0]["effect"] == "offset" and report["unexplained"] < 0.01
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 5  # maps, shares, spectrum, shrinks, samples
    assert 'src="http' not in page and "<table>" in page


def test_diagnose_bad_input_names_the_file(
    tmp_path: Path, backend: list[str] | None, capsys: pytest.CaptureFixture[str]
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
def test_diagnose_stage(tmp_path: Path, backend: list[str] | None) -> None:
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


def _summary_report(**fields: Any) -> dict[str, Any]:
    """The fields ``_summary_lines`` reads of a diagnosis of 8 pairs, with ``fields`` on top."""
    base = {
        "n_pairs": 8,
        "split": {"n_fit": 4, "n_held": 4},
        "timing_s": {"total": 1.0},
        "where": {"mse": 3.0, "dominant": []},
        "ranking": [],
        "unexplained": 0.0,
        "residual_flagged": False,
    }
    return base | fields


def test_summary_lines_tolerate_any_how_far_fields() -> None:
    from tactile_bench.diagnose.commands import _summary_lines

    where = {"mse": 3.0, "dominant": [{"axis": "band", "part": "DC", "share": 0.5}]}
    report = _summary_report(
        where=where,
        unexplained=1.0,
        residual_flagged=True,
        how_far={
            "pixel": {"before": {"mse": 9.0, "ssim": 0.5}, "after": {"mse": 4.0, "ssim": 0.7}},
            "distribution": {"kid_before": 0.1, "kid_after": None},
            "downstream": {"classes": 3, "classifier": "tiny", "real_accuracy": 0.9},
        },
    )
    text = "\n".join(_summary_lines(report))
    assert "mse 9 -> 4" in text and "real 0.9" in text and "no candidate" in text


def test_the_summary_warns_when_the_depth_split_names_another_effect() -> None:
    from tactile_bench.diagnose.commands import _summary_lines

    stability = {
        "named_first": "led_diffusivity",
        "agrees": False,
        "n_fit": 50,
        "n_held": 50,
        "depth_fit_mm": 0.9,
        "depth_held_mm": 1.1,
        "accepted": ["optical_response", "elastic_spread"],
    }
    report = _summary_report(unexplained=0.02, stability=stability)
    text = "\n".join(_summary_lines(report))
    assert "names led_diffusivity first" in text and "outside the candidates" in text
    assert "no candidate explains" not in text  # the residual itself is small
    agreeing = {**report, "stability": {**stability, "agrees": True}}
    assert "names led_diffusivity" not in "\n".join(_summary_lines(agreeing))


def test_first_lines_show_the_background_line_sim_optics_and_confusable_sets() -> None:
    from tactile_bench.diagnose.commands import _summary_lines

    where = {"mse": 3.0, "dominant": []}
    fit = {"effect": "vignetting", "shrink": 0.6, "ci_low": 0.5, "ci_high": 0.7}
    report = {
        "n_pairs": 8,
        "split": {"n_fit": 4, "n_held": 4},
        "timing_s": {"total": 1.0},
        "where": where,
        "background": {"shrink": 0.42, "ci_low": 0.4, "ci_high": 0.44},
        "which": {"sim_optics": {"model": "fitted lookup", "builtin_mse": 9.0, "lookup_mse": 1.0}},
        "ranking": [
            {
                **fit,
                "gap_before": 2.0,
                "gap_after": 0.8,
                "confusable_with": ["optical_response"],
                "separate_by": "a flat press",
            }
        ],
        "unexplained": 0.1,
        "residual_flagged": False,
    }
    lines = _summary_lines(report)
    assert lines[1].startswith("background:") and "0.420 [0.400, 0.440]" in lines[1]
    assert lines[2].startswith("sim optics for geometry effects: fitted lookup")
    assert lines[3] == (
        "confusable: vignetting ~ optical_response (the held-out pairs cannot tell them apart)"
    )
    composited = {**report, "background": None, "background_note": "the sim was composited"}
    assert _summary_lines(composited)[1] == "background: the sim was composited"


def test_the_summary_says_unexplained_is_counted_above_the_pairs_noise() -> None:
    from tactile_bench.diagnose.commands import _summary_lines

    report = _summary_report(which={"noise": {"sim": [0.0, 0.0, 0.0], "real": [2.1, 2.4, 2.2]}})
    text = "\n".join(_summary_lines(report))
    assert "counted above the pairs' own noise (std, grey levels: sim 0, real 2.4)" in text
