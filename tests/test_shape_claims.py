"""The paper's claims (and our calibrated-simulator claim) are decided by the measured rows."""

from __future__ import annotations

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
