"""The paper's claims (and our calibrated-simulator claim) are decided by the measured rows."""

from __future__ import annotations

import math

import pytest

from tactile_bench.report.shape import shape_checks


def _rows(**accuracy: float) -> list[dict[str, object]]:
    return [{"row": row, "accuracy": value / 100} for row, value in accuracy.items()]


def _claim(checks: list[dict[str, object]], start: str) -> dict[str, object]:
    return next(c for c in checks if str(c["claim"]).startswith(start))


def test_calibrated_claim_holds_only_at_or_above_sim_ft20() -> None:
    above = _claim(shape_checks(_rows(calibrated=70.0, sim_ft20=65.0)), "Calibrated sim")
    below = _claim(shape_checks(_rows(calibrated=60.0, sim_ft20=65.0)), "Calibrated sim")
    assert above["holds"] is True and below["holds"] is False
    assert "calibrated 70.00%" in str(above["measured"])


def test_a_claim_whose_rows_are_missing_is_skipped_not_held() -> None:
    checks = shape_checks(_rows(sim_ft20=65.0, sim=30.0))
    assert not any(str(c["claim"]).startswith("Calibrated sim") for c in checks)
    assert _claim(checks, "Sim + 20% fine-tuning is above Sim")["holds"] is True


def test_fine_tuning_claim_needs_the_three_fractions_in_order() -> None:
    rising = shape_checks(_rows(sim_ft20=60.0, sim_ft80=70.0, sim_ft100=71.0))
    falling = shape_checks(_rows(sim_ft20=68.0, sim_ft80=62.0, sim_ft100=64.0))
    assert _claim(rising, "fine-tuning rises")["holds"] is True
    assert _claim(falling, "fine-tuning rises")["holds"] is False


def _seeded(**mean_std: tuple[float, float]) -> list[dict[str, object]]:
    """Rows measured over three classifier seeds: (mean %, seed std %)."""
    return [
        {"row": row, "accuracy": {"mean": m / 100, "std": s / 100}, "extra": {"seeds": [0, 1, 2]}}
        for row, (m, s) in mean_std.items()
    ]


def test_a_difference_within_seed_noise_is_undecided_whichever_way_it_falls() -> None:
    # 74.59 vs 74.35 with seed stds 5.6 and 7.3: table1's 80% and 100% rows on 2026-11-27
    close = _seeded(sim_ft20=(71.60, 2.02), sim_ft80=(74.59, 5.58), sim_ft100=(74.35, 7.30))
    check = _claim(shape_checks(close), "fine-tuning rises")
    assert check["holds"] is False and check["decided"] is False
    assert check["gap"] == pytest.approx(-0.24)
    # standard error of the 100% - 80% difference: sqrt(5.58^2 / 3 + 7.30^2 / 3)
    assert check["gap_error"] == pytest.approx(math.hypot(5.58, 7.30) / math.sqrt(3))
    apart = _seeded(sim_ft20=(60.0, 1.0), sim_ft80=(70.0, 1.0), sim_ft100=(80.0, 1.0))
    check = _claim(shape_checks(apart), "fine-tuning rises")
    assert check["holds"] is True and check["decided"] is True


def test_a_failure_is_decided_by_its_clearest_gap_and_a_hold_needs_every_gap() -> None:
    # 80% clearly below 20%, 100% within noise of 80%: a decided failure
    fails = _seeded(sim_ft20=(80.0, 1.0), sim_ft80=(60.0, 1.0), sim_ft100=(60.5, 5.0))
    check = _claim(shape_checks(fails), "fine-tuning rises")
    assert check["holds"] is False and check["decided"] is True
    assert check["gap"] == pytest.approx(-20.0)
    # both steps up, the second within noise: a hold the seeds do not decide
    weak = _seeded(sim_ft20=(60.0, 1.0), sim_ft80=(70.0, 1.0), sim_ft100=(70.5, 5.0))
    check = _claim(shape_checks(weak), "fine-tuning rises")
    assert check["holds"] is True and check["decided"] is False
    assert check["gap"] == pytest.approx(0.5)


def test_a_threshold_claim_counts_its_distance_to_the_threshold() -> None:
    assert _claim(shape_checks(_seeded(real=(100.0, 0.0))), "Real is near")["decided"] is True
    near = _claim(shape_checks(_seeded(real=(96.0, 2.0))), "Real is near")
    assert near["holds"] is True and near["decided"] is False  # 1 point above, s.e. 1.15


def test_every_claim_explained_in_the_docs_names_a_claim_and_a_section_there() -> None:
    """The report points failing claims at their experiments: both ends must exist."""
    from pathlib import Path

    from tactile_bench.report.shape import CLAIMS, EXPERIMENTS, EXPERIMENTS_DOC

    claims = {c[0] for c in CLAIMS} | {"diffusion SSIM is above cGAN SSIM"}
    assert set(EXPERIMENTS) <= claims
    doc = (Path(__file__).resolve().parents[1] / EXPERIMENTS_DOC).read_text()
    headings = {line.lstrip("#").strip() for line in doc.splitlines() if line.startswith("#")}
    assert set(EXPERIMENTS.values()) <= headings


def test_a_row_over_one_seed_leaves_the_claim_undecidable_not_decided() -> None:
    rows = [
        {"row": "sim_ft20", "accuracy": {"mean": 0.60, "std": 0.0}, "extra": {"seeds": [0]}},
        {"row": "sim", "accuracy": {"mean": 0.30, "std": 0.0}, "extra": {"seeds": [0]}},
    ]
    check = _claim(shape_checks(rows), "Sim + 20% fine-tuning is above Sim")
    assert check["holds"] is True and check["decided"] is None
