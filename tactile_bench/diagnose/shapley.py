"""Each selected effect's share of the explained gap, independent of the order they were added.

The greedy ranking's shrinks depend on the order: an effect's shrink is what it removes after
the ones before it. The Shapley value (Shapley 1953, "A value for n-person games") is instead
each effect's mean marginal removal of the held-out gap over every order in which the set
could be built, the shares summing to the gap the whole set removes. That is how Budhathoki,
Janzing, Bloebaum & Ng (2021, "Why did the distribution change?", AISTATS; DoWhy's
``gcm.distribution_change``) attribute a change of distribution to the mechanisms that
changed. Here a coalition is a subset of the selected effects, refitted on the fit split on
its own, and its value the held-out gap it leaves (exact over every subset: 2-5 effects are a
handful of refits). The interval resamples the held-out pairs, every coalition on the same
resample.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import torch

from tactile_bench.diagnose.bootstrap import BOOTSTRAP, interval95, resampled
from tactile_bench.diagnose.breakdown import BOOTSTRAP as BOOTSTRAP_SPAN
from tactile_bench.sensor.timing import timed_span

#: a coalition's held-out gap per pair
CoalitionGaps = Mapping[frozenset[str], torch.Tensor]


@dataclass
class ShapleyShare:
    """One effect's Shapley share of the initial held-out gap, with its bootstrap 95% CI
    (the shares of the selected effects sum to the share the whole set removes)."""

    effect: str
    share: float
    ci_low: float
    ci_high: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def shapley_values(players: Sequence[str], gaps: CoalitionGaps) -> dict[str, torch.Tensor]:
    """Each player's Shapley value of the gap removed: its marginal ``gaps[T] - gaps[T + i]``
    weighted by ``|T|! (n - |T| - 1)! / n!`` over the coalitions ``T`` without it. A
    coalition's value is a tensor (one gap, or one per bootstrap resample)."""
    n = len(players)
    values = {}
    for player in players:
        others = [p for p in players if p != player]
        total = torch.zeros_like(gaps[frozenset()])
        for k in range(n):
            weight = math.factorial(k) * math.factorial(n - k - 1) / math.factorial(n)
            for coalition in itertools.combinations(others, k):
                without = frozenset(coalition)
                total = total + weight * (gaps[without] - gaps[without | {player}])
        values[player] = total
    return values


def shapley_shares(
    players: Sequence[str], gaps: CoalitionGaps, seed: int = 0, n: int = BOOTSTRAP
) -> list[ShapleyShare]:
    """Each player's Shapley value as a share of the empty coalition's held-out gap (``gaps``:
    each coalition's gap per held-out pair), with a bootstrap 95% CI; by name, so that the
    answer does not depend on the order the players came in."""
    players = sorted(players)
    n_pairs = len(gaps[frozenset()])
    point = shapley_values(players, {c: g.double().mean() for c, g in gaps.items()})
    base = float(gaps[frozenset()].double().mean())
    out = []
    with timed_span(BOOTSTRAP_SPAN):
        idx = resampled(n_pairs, seed, n)
        gaps_drawn = {c: g.double()[idx].mean(1) for c, g in gaps.items()}
        draws = shapley_values(players, gaps_drawn)
        for player in players:
            share = float(point[player]) / base if base > 0 else 0.0
            ratio = draws[player] / gaps_drawn[frozenset()].clamp(min=1e-12)
            lo, hi = interval95(ratio)
            # a percentile interval can miss its own estimate on degenerate data: it holds it
            out.append(ShapleyShare(player, share, min(lo, share), max(hi, share)))
    return out
