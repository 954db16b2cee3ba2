"""Shapley shares of the explained gap: efficient, symmetric, null for a dummy, order-free."""

from __future__ import annotations

import itertools

import pytest
import torch

from tactile_bench.diagnose.shapley import shapley_shares, shapley_values
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank


def _coalitions(players: list[str], gap_of) -> dict[frozenset[str], torch.Tensor]:
    """Every coalition's per-pair gap, from ``gap_of(coalition)`` (a tensor of pairs)."""
    return {
        frozenset(c): gap_of(frozenset(c))
        for k in range(len(players) + 1)
        for c in itertools.combinations(players, k)
    }


def test_two_effects_by_hand() -> None:
    gaps = {frozenset(): 10.0, frozenset("a"): 4.0, frozenset("b"): 6.0, frozenset("ab"): 2.0}
    values = shapley_values(["a", "b"], {k: torch.tensor(v) for k, v in gaps.items()})
    # a: (10 - 4 + 6 - 2) / 2; b: (10 - 6 + 4 - 2) / 2
    assert float(values["a"]) == pytest.approx(5.0) and float(values["b"]) == pytest.approx(3.0)


def test_shares_sum_to_the_explained_gap() -> None:
    gen = torch.Generator().manual_seed(0)
    per_pair = torch.rand(40, generator=gen) + 1.0
    removes = {"blur": 0.5, "spread": 0.3, "noise": 0.1}

    def gap_of(c: frozenset[str]) -> torch.Tensor:  # interacting: blur and spread overlap
        left = 1.0 - sum(removes[e] for e in c) + (0.2 if {"blur", "spread"} <= c else 0.0)
        return per_pair * left

    gaps = _coalitions(list(removes), gap_of)
    shares = shapley_shares(list(removes), gaps)
    explained = 1 - float(gaps[frozenset(removes)].mean()) / float(gaps[frozenset()].mean())
    assert sum(s.share for s in shares) == pytest.approx(explained)
    assert all(s.ci_low <= s.share <= s.ci_high for s in shares)


def test_interchangeable_effects_get_equal_shares() -> None:
    per_pair = torch.linspace(1.0, 2.0, 30)

    def gap_of(c: frozenset[str]) -> torch.Tensor:  # a and b do the same; either suffices
        return per_pair * (1.0 - 0.6 * bool(c & {"a", "b"}) - 0.2 * ("c" in c))

    shares = {
        s.effect: s for s in shapley_shares(["a", "b", "c"], _coalitions(["a", "b", "c"], gap_of))
    }
    assert shares["a"].share == pytest.approx(shares["b"].share) == pytest.approx(0.3)
    assert shares["c"].share == pytest.approx(0.2)


def test_an_effect_that_changes_nothing_gets_zero() -> None:
    per_pair = torch.linspace(1.0, 3.0, 25)

    def gap_of(c: frozenset[str]) -> torch.Tensor:
        return per_pair * (1.0 - 0.5 * ("real" in c))

    shares = {
        s.effect: s
        for s in shapley_shares(["real", "dummy"], _coalitions(["real", "dummy"], gap_of))
    }
    assert shares["dummy"].share == 0.0 and shares["dummy"].ci_low == shares["dummy"].ci_high == 0.0
    assert shares["real"].share == pytest.approx(0.5)


def test_the_players_order_does_not_matter() -> None:
    gen = torch.Generator().manual_seed(1)
    table = {c: torch.rand(20, generator=gen) for c in _coalitions(["x", "y", "z"], lambda c: 0)}
    first = shapley_shares(["x", "y", "z"], table, seed=3)
    assert first == shapley_shares(["z", "x", "y"], table, seed=3)


def test_the_diagnosis_shares_do_not_depend_on_the_candidate_order() -> None:
    """Two planted effects, the candidates given in two orders: the same selection and the
    same Shapley shares, which sum to what the selection removes."""
    bank = build_bank(("A", "L", "#"), BrailleSpec())
    planted = {"vignetting": {"corner_loss": 0.4}, "led_diffusivity": {"gain_r": 1.3}}
    data = planted_pairs(bank, planted, 24, 3, 32)
    fit, held = torch.arange(0, 24, 2), torch.arange(1, 24, 2)
    names = ["vignetting", "led_diffusivity", "defocus_blur"]
    results = [
        explain_gap(data, fit, held, order, seed=0, progress=False, stability=False)
        for order in (names, names[::-1])
    ]
    assert results[0].shapley == results[1].shapley
    result = results[0]
    assert {s.effect for s in result.shapley} == set(result.selected_params)
    explained = 1 - result.gap_after / result.gap_before
    assert sum(s.share for s in result.shapley) == pytest.approx(explained, abs=1e-6)
