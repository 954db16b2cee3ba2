"""validate-diagnosis: the planting rule, the cases, one blind case end to end, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.diagnose.candidates import DEFAULT_CANDIDATES
from tactile_bench.diagnose.shrink import Downstream, KidScores, Skipped, how_far
from tactile_bench.diagnose.validate import (
    Case,
    draw_params,
    make_cases,
    planted_pairs,
    run_case,
    verdict,
)
from tactile_bench.diagnose.validate_report import markdown, summarise
from tactile_bench.effects import EFFECTS
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit


@pytest.fixture(scope="module")
def bank():
    return build_bank(("A", "L", "#"), BrailleSpec())


@pytest.mark.parametrize("name", list(EFFECTS))
def test_planted_parameters_are_in_range_and_far_from_neutral(name: str) -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        drawn = draw_params(name, rng)
        EFFECTS[name].validate(drawn)  # float32 range check of the effects themselves
        for p in EFFECTS[name].params:
            v = drawn[p.name]
            assert p.low <= v <= p.high
            if p.name != "unit_seed" and not p.integer:
                room = (p.high if v > p.neutral else p.low) - p.neutral
                assert abs(v - p.neutral) >= 0.249 * abs(room), (p.name, v)


def test_cases_cover_the_catalogue_and_withhold_effects() -> None:
    cases = make_cases(quick=False, seed=0)
    singles = [c.planted[0] for c in cases if c.kind == "single"]
    assert singles == [*DEFAULT_CANDIDATES, "unit_background"]
    assert sum(c.kind == "double" for c in cases) >= 4
    outs = [c for c in cases if c.kind == "out_of_catalogue"]
    assert {c.planted[0] for c in outs} >= {"shadows", "defocus_blur"}
    for c in outs:  # the planted effect is never among the candidates
        assert c.planted[0] in c.removed or c.planted[0] not in DEFAULT_CANDIDATES
    assert any(c.removed for c in outs)
    again = make_cases(quick=False, seed=0)
    assert [c.params for c in again] == [c.params for c in cases]  # seeded
    assert make_cases(quick=False, seed=1)[0].params != cases[0].params


def test_planted_pairs_hide_nothing_but_the_effect(bank) -> None:
    data = planted_pairs(bank, {"vignetting": {"corner_loss": 0.5}}, 6, 1, 32)
    plain = SurrogateDigit({})
    assert torch.equal(data.sim_background, plain.background(32).round())
    assert not torch.equal(data.background, data.sim_background)  # the real unit's frame
    assert data.depth.shape == (6, 1, 32, 32) and float(data.depth.max()) > 0
    assert set(data.labels) <= {"A", "L", "#"}


def test_one_blind_case_end_to_end(bank) -> None:
    keep = ("vignetting", "led_diffusivity", "gamma_white_balance", "defocus_blur")
    case = Case(
        "vignetting",
        "single",
        ["vignetting"],
        removed=tuple(c for c in DEFAULT_CANDIDATES if c not in keep),  # a quick test
        params={"vignetting": {"corner_loss": 0.5}},
    )
    row = run_case(case, bank, n=24, seed=0, size=32, index=0)
    assert row["top1"] == "vignetting" and row["passed"]
    assert row["rank_of_true"] == {"vignetting": 1}
    true, fitted = row["fitted_vs_true"]["vignetting"]["corner_loss"]
    assert true == 0.5 and abs(fitted - true) < 0.05
    assert row["pixel"]["after"]["mse"] < 0.1 * row["pixel"]["before"]["mse"]
    summary = summarise([row])
    assert summary["top1_accuracy"] == 1.0
    text = markdown(
        {**summary, "n_pairs": 24, "size": 32, "seed": 0, "quick": True, "seconds": 1.0}, [row]
    )
    assert "| vignetting | single |" in text


def test_out_of_catalogue_case_is_not_blamed(bank) -> None:
    case = Case(
        "defocus (withheld)",
        "out_of_catalogue",
        ["defocus_blur"],
        removed=tuple(
            c
            for c in DEFAULT_CANDIDATES
            if c not in ("vignetting", "unit_background", "defocus_blur")
        )
        + ("defocus_blur",),
        params={"defocus_blur": {"sigma_mm": 0.6}},
    )
    row = run_case(case, bank, n=24, seed=0, size=32, index=1)
    assert row["residual_flagged"] and not row["blamed_with_high_confidence"] and row["passed"]


def test_how_far_reports_pixel_distribution_and_skips_downstream(bank, monkeypatch) -> None:
    monkeypatch.setattr("tactile_bench.diagnose.shrink.ENCODER_STEPS", 30)
    data = planted_pairs(bank, {"vignetting": {"corner_loss": 0.5}}, 16, 2, 32)
    idx = torch.arange(16)
    out = how_far(data, idx[:8], idx[8:], {"vignetting": {"corner_loss": 0.5}}, downstream=False)
    assert out.pixel_after["mse"] < out.pixel_before["mse"]
    assert out.pixel_after["ssim"] > out.pixel_before["ssim"]
    assert isinstance(out.distribution, KidScores) and out.distribution.kid_before > 0
    assert out.downstream == Skipped("--no-downstream")
    unlabelled = planted_pairs(bank, {}, 8, 2, 32)
    unlabelled.labels = [""] * 8
    down = how_far(unlabelled, idx[:4], idx[4:8], {}, seed=0).downstream
    assert isinstance(down, Skipped) and "unlabelled" in down.reason


@pytest.mark.slow
def test_how_far_downstream_trains_both_classifiers(bank) -> None:
    data = planted_pairs(bank, {"optical_response": {"blend": 1.0}}, 48, 2, 32)
    idx = torch.arange(48)
    out = how_far(data, idx[:24], idx[24:], {"optical_response": {"blend": 1.0}})
    d = out.downstream
    assert isinstance(d, Downstream)
    assert all(0.0 <= v <= 1.0 for v in d.accuracies.values())
    noise = d.noise  # estimated from the pairs: real's own level adds nothing to real
    assert len(noise["real_std"]) == 3 and noise["real"]["added"] == [0.0, 0.0, 0.0]
    assert {"plain_sim", "sim_plus_effects"} <= set(noise) and noise["copies"] >= 1


@pytest.mark.slow
def test_cli_quick_validation_writes_json_and_markdown(tmp_path) -> None:
    out = tmp_path / "val"
    code = main(
        ["validate-diagnosis", "--quick", "--pairs", "40", "--size", "32", "--out", str(out),
         "--no-progress"]
    )  # fmt: skip
    assert code == 0
    report = json.loads((out / "validation.json").read_text())
    assert report["summary"]["n_single"] == 4 and len(report["cases"]) >= 6
    assert "top-1 identification" in (out / "validation.md").read_text()


def test_foreign_suite_cases_span_shadings_variants_and_withheld_plants() -> None:
    cases = make_cases(quick=False, seed=0, suites=("foreign",))
    assert {c.suite for c in cases} == {"foreign"}
    variants = {c.foreign[2] for c in cases}
    assert variants == {"own", "composited"}
    outs = [c for c in cases if c.kind == "out_of_catalogue"]
    for c in outs:  # a plant whose catalogue name is no candidate must be flagged
        assert c.planted[0] not in DEFAULT_CANDIDATES
    assert {c.foreign[0] for c in outs} >= {"barrel", "chromatic"}
    assert make_cases(quick=False, seed=0, suites=("foreign",))[3].params == cases[3].params


def test_lens_blur_cases_in_both_suites_each_told_apart_or_confusable() -> None:
    cases = make_cases(quick=True, seed=0, suites=("own", "foreign"))
    told = [c for c in cases if c.kind == "named_or_confusable"]
    assert {c.suite for c in told} == {"own", "foreign"}
    lens = [c for c in told if c.required == ("defocus_blur",)]
    double = [c for c in told if c.required == ("defocus_blur", "elastic_spread")]
    assert len(lens) >= 3 and len(double) >= 3  # own, and each foreign shading and variant
    own_lens = next(c for c in lens if c.suite == "own")
    assert list(own_lens.params) == ["defocus_blur", "camera_noise"]  # noise after the blur
    # the earlier cases keep their index, so their data and split are the ones they had
    assert cases.index(told[0]) == len(cases) - len(told)


def test_a_blur_blamed_on_the_spread_with_confidence_fails() -> None:
    case = Case("lens", "named_or_confusable", ["defocus_blur"], required=("defocus_blur",))
    blamed = {"selected": ["elastic_spread", "camera_noise"], "confusable": {}}
    out = verdict(case, blamed)
    assert out["missing"] == ["defocus_blur"] and not out["passed"]
    said = {"selected": ["elastic_spread"], "confusable": {"elastic_spread": ["defocus_blur"]}}
    assert verdict(case, said)["passed"]
    named = {"selected": ["defocus_blur", "camera_noise"], "confusable": {}}
    assert verdict(case, named)["passed"]


def test_the_summary_counts_lens_and_gel_cases_told_apart() -> None:
    case = Case("lens", "named_or_confusable", ["defocus_blur"], required=("defocus_blur",))
    said = {"selected": ["elastic_spread"], "confusable": {"elastic_spread": ["defocus_blur"]}}
    blamed = {"selected": ["elastic_spread"], "confusable": {}}
    rows = [{**r, "kind": case.kind, **verdict(case, r)} for r in (said, blamed)]
    summary = summarise(rows)
    assert (summary["n_told_apart"], summary["told_apart"]) == (2, 1)
    lines = markdown(
        {**summary, "n_pairs": 2, "size": 32, "seed": 0, "quick": True, "seconds": 1}, []
    )
    assert "found confusable (never blamed on the other): 1/2" in lines


def test_one_foreign_case_end_to_end(bank) -> None:
    keep = ("vignetting", "led_diffusivity", "defocus_blur", "camera_noise")
    case = Case(
        "vignetting (lambert, own)",
        "single",
        ["vignetting"],
        removed=tuple(c for c in DEFAULT_CANDIDATES if c not in keep),
        params={"vignetting": {"corner_loss": 0.3}},
        suite="foreign",
        foreign=("vignetting", "lambert", "own"),
    )
    row = run_case(case, bank, n=24, seed=0, size=32, index=0)
    assert row["suite"] == "foreign" and row["renderer"] == "foreign lambert"
    assert row["background_share"] is not None and row["background_share"] > 0.5
    assert row["expected"] == "vignetting" and row["passed"] == (row["top1"] == "vignetting")
    assert row["fitted_vs_true"] == {}  # the foreign renderer names its own parameters
