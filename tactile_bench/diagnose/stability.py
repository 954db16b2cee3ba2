"""Is the explanation the sensor's? The selection re-run on shallow presses, held out on deep.

An effect of the sensor has one set of parameters whatever the press, so fitted on the
shallowest presses it still names itself on the deepest: the invariance across environments
that Peters, Buehlmann & Meinshausen (2016, "Causal inference by using invariant prediction",
JRSS B 78(5)) use to tell a causal model from one that only fits. An effect outside the
candidates is mimicked by a different mix of candidates at each depth (measured in
docs/diagnosis.md, with ``scripts/diagnosis_depth_split.py``).

``check`` takes the re-run as a callable so that this module does not import the selection.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import torch

#: pairs the re-run uses at most: the shallowest half fitted, the deepest half held out
STABILITY_PAIRS = 100
MIN_PAIRS = 8  # fewer pairs than this and each half is too small to select anything


class Ranked(Protocol):
    """What the check reads of a ranking entry (``which.EffectFit``)."""

    effect: str
    confusable_with: list[str]


@dataclass
class Stability:
    """What the depth split names first, and whether the full selection allows it."""

    named_first: str | None  # None: the depth split selects nothing
    agrees: bool
    n_fit: int
    n_held: int
    depth_fit_mm: float  # deepest press of the fitted half
    depth_held_mm: float  # shallowest press of the held-out half
    accepted: list[str] = field(default_factory=list)  # selected effects and their rivals

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def depth_halves(
    depth: torch.Tensor, n_max: int = STABILITY_PAIRS
) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices of the shallowest and the deepest ``n_max // 2`` pairs by peak penetration
    (ties in index order, so the split is the same on every run)."""
    peak = depth.flatten(1).amax(1)
    order = torch.sort(peak, stable=True).indices
    k = min(len(order), n_max) // 2
    return order[:k], order[len(order) - k :]


def check(
    ranking: Sequence[Ranked],
    depth: torch.Tensor,
    rerun: Callable[[torch.Tensor, torch.Tensor], Sequence[Ranked]],
) -> Stability | None:
    """Re-run the selection (``rerun(fit_idx, held_idx)``) with the shallow presses fitted and
    the deep ones held out. It agrees when it names first one of the selected effects or one
    the held-out pairs could not tell from them (``confusable_with``), or nothing; None when
    nothing was selected or the pairs are too few to split."""
    if not ranking or len(depth) < MIN_PAIRS:
        return None
    shallow, deep = depth_halves(depth)
    named = list(rerun(shallow, deep))
    first = named[0].effect if named else None
    accepted = list(dict.fromkeys(e for r in ranking for e in (r.effect, *r.confusable_with)))
    peak = depth.flatten(1).amax(1)
    return Stability(
        named_first=first,
        agrees=first is None or first in accepted,
        n_fit=len(shallow),
        n_held=len(deep),
        depth_fit_mm=round(float(peak[shallow].max()), 4),
        depth_held_mm=round(float(peak[deep].min()), 4),
        accepted=accepted,
    )


def warning(stability: Stability | None) -> str | None:
    """The report's sentence when the depth split disagrees, else None."""
    if stability is None or stability.agrees:
        return None
    first, accepted = stability.named_first, " / ".join(stability.accepted)
    return (
        f"fitted on the {stability.n_fit} shallowest presses (to "
        f"{stability.depth_fit_mm:.2f} mm) and scored on the {stability.n_held} deepest "
        f"(from {stability.depth_held_mm:.2f} mm), the selection names {first} first, which "
        f"it neither selects nor finds confusable with {accepted}: the explanation depends on "
        f"the presses it was fitted on, so an effect is missing from it ({first}, or one "
        "outside the candidates). Presses of one shape at several depths would show which"
    )
