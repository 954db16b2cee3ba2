"""The selection refits nothing after its last allowed round (issue 47): the depth split's
first round fits each candidate once."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from tactile_bench.diagnose import which
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.effects import EFFECTS
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank

# two effects of similar size: the first round's pick leaves a gap worth a refit round
PLANTED = {"vignetting": {"corner_loss": 0.5}, "gamma_white_balance": {"gamma": 1.5}}
NAMES = list(PLANTED)


# ------------------------------------------------------------------ first round
@pytest.fixture(scope="module")
def two_effects() -> DiagnosisPairs:
    bank = build_bank(("A", "L", "#"), BrailleSpec())
    planted = {k: {**EFFECTS[k].neutral_params(), **v} for k, v in PLANTED.items()}
    return planted_pairs(bank, planted, 12, 3, 32)


@pytest.fixture
def fit_count(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names ``which`` fits, call by call (the real fits run)."""
    fitted: list[str] = []
    real = which.fit_candidate

    def counted(name: str, *args: Any, **kwargs: Any) -> dict[str, float]:
        fitted.append(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(which, "fit_candidate", counted)
    return fitted


def test_first_round_fits_each_candidate_once(two_effects, fit_count) -> None:
    idx = torch.arange(len(two_effects))
    rows = which.first_round(two_effects, idx[::2], idx[1::2], NAMES, 0)
    assert len(rows) == 1 and rows[0].effect in NAMES
    assert sorted(fit_count) == sorted(NAMES)  # each once, no refit
    # the same data with a second round allowed: the other candidate is refitted, so
    # the first round alone left a gap a refit would have been made for
    fit_count.clear()
    kw: dict[str, Any] = {"progress": False, "stability": False, "attribution": False}
    which.explain_gap(two_effects, idx[::2], idx[1::2], NAMES, max_rounds=2, **kw)
    assert len(fit_count) == len(NAMES) + 1
