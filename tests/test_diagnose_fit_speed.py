"""The diagnosis's fits stop when they stop gaining (issue 47): Adam ends once it stalls, and
the depth split's first round fits each candidate once, refitting none."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import pytest
import torch

from tactile_bench.diagnose import which
from tactile_bench.diagnose.gapfit import ADAM_PATIENCE, FitBudget, _adam, _stalled
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.effects import EFFECTS
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank

# two effects of similar size: the first round's pick leaves a gap worth a refit round
PLANTED = {"vignetting": {"corner_loss": 0.5}, "gamma_white_balance": {"gamma": 1.5}}
NAMES = list(PLANTED)


def _counting(loss: Callable[[Mapping[str, Any]], torch.Tensor], seen: list[float]) -> Any:
    """``loss`` that records the coordinate ``a`` of every point it scores."""

    def counted(u: Mapping[str, Any]) -> torch.Tensor:
        seen.append(float(torch.as_tensor(u["a"]).detach()))
        return loss(u)

    return counted


def _bowl(u: Mapping[str, Any]) -> torch.Tensor:
    return ((u["a"] - 0.8) ** 2).sum()


# ------------------------------------------------------------------ _stalled
def test_too_short_a_trace_never_stalls() -> None:
    for n in range(ADAM_PATIENCE + 1):
        assert not _stalled([3.0] * n)


def test_a_flat_trace_stalls() -> None:
    assert _stalled([3.0] * (ADAM_PATIENCE + 1))
    # a gain far below ADAM_MIN_GAIN of the best is still a stall
    assert _stalled([3.0] * ADAM_PATIENCE + [3.0 * (1 - 1e-5)])


def test_a_steadily_falling_trace_does_not_stall() -> None:
    trace = [10.0 * 0.99**i for i in range(40)]  # each step 1% lower
    assert not any(_stalled(trace[:n]) for n in range(len(trace) + 1))


# ------------------------------------------------------------------ _adam
def test_adam_stops_on_a_flat_loss() -> None:
    seen: list[float] = []
    u: dict[str, Any] = {"a": 0.3}
    flat = _counting(lambda v: (v["a"] * 0).sum() + 5, seen)
    _adam(u, ["a"], flat, FitBudget(adam_steps=25))
    assert len(seen) <= ADAM_PATIENCE + 1
    assert u["a"] == pytest.approx(0.3)  # nothing gained: the start is kept


def test_adam_descends_a_bowl_and_keeps_its_best_point() -> None:
    seen: list[float] = []
    u: dict[str, Any] = {"a": 0.2}
    _adam(u, ["a"], _counting(_bowl, seen), FitBudget(adam_steps=25))
    assert abs(u["a"] - 0.8) < 0.05  # from 0.6 away
    assert len(seen) <= 25  # no extra evaluation after a stall
    assert u["a"] == min(seen, key=lambda a: (a - 0.8) ** 2)  # the best point scored


def test_adam_that_runs_all_its_steps_scores_the_last_point() -> None:
    """No stall in 3 steps: the point the last step moved to is scored once more (the
    ``for``'s ``else``) and kept, being the best."""
    seen: list[float] = []
    u: dict[str, Any] = {"a": 0.2}
    _adam(u, ["a"], _counting(_bowl, seen), FitBudget(adam_steps=3))
    assert len(seen) == 4
    assert u["a"] == pytest.approx(seen[-1]) and seen[-1] > max(seen[:-1])


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
