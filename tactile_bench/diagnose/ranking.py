"""One round of the selection: each option's share of the held-out gap with its bootstrap
interval, the rivals the held-out pairs cannot tell from it, and the effect the round picks."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch

from tactile_bench.diagnose.bootstrap import BOOTSTRAP, interval95, resampled
from tactile_bench.diagnose.breakdown import BOOTSTRAP as BOOTSTRAP_SPAN
from tactile_bench.diagnose.candidates import get_candidate
from tactile_bench.diagnose.gapfit import PostDraw, Target, model_gap
from tactile_bench.diagnose.no_contact import FrameCheck, FrameReading
from tactile_bench.diagnose.scene import PairScene
from tactile_bench.diagnose.simulate import render
from tactile_bench.sensor.timing import timed_span

#: an option removing this share of what is left is a rival explanation across the lens /
#: gel line when the no-contact frame cannot read the lens
STRONG_RIVAL = 0.25
# RMS of 8-bit rounding (1/sqrt(12) grey level): fitted images closer than this are the
# same image as far as 8-bit frames can show
PIXEL_NOISE = 1 / math.sqrt(12)
#: each remaining candidate: (its fitted parameters, the held-out per-pair gap with it added)
Options = Mapping[str, tuple[dict[str, float], torch.Tensor]]
Selected = Mapping[str, Mapping[str, float]]


@dataclass
class EffectFit:
    """One candidate's fit and how much of the held-out gap it removes."""

    effect: str
    params: dict[str, float]
    gap_before: float
    gap_after: float
    shrink: float  # (gap_before - gap_after) / gap_before on the held-out split
    ci_low: float  # bootstrap 95% CI of shrink (resampling held-out pairs)
    ci_high: float
    # rivals at the same round the held-out pairs cannot tell from this one: the paired
    # bootstrap 95% CI of (rival's gap - this one's) / gap_before reaches 0; or a strong
    # rival across the lens / gel line when the no-contact frame cannot read the lens
    confusable_with: list[str] = field(default_factory=list)
    separate_by: str = ""  # what measurement would tell them apart
    # a camera effect's reading on the no-contact frame at these parameters (None: not one
    # the frame shows)
    no_contact: FrameReading | None = None

    @classmethod
    def measure(
        cls,
        name: str,
        params: dict[str, float],
        before: torch.Tensor,
        after: torch.Tensor,
        seed: int,
    ) -> EffectFit:
        """The row of an effect that takes the per-pair gap from ``before`` to ``after``."""
        b, a = float(before.mean()), float(after.mean())
        shrink = (b - a) / b if b > 0 else 0.0
        lo, hi = shrink_ci(before, after, seed)
        # a percentile interval of a skewed ratio can miss its own estimate (degenerate
        # data): the reported interval always holds it
        return cls(name, params, b, a, shrink, min(lo, shrink), max(hi, shrink))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def shrink_ci(
    before: torch.Tensor, after: torch.Tensor, seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float, float]:
    """Bootstrap 95% CI of ``1 - sum(after) / sum(before)`` over resampled pairs."""
    with timed_span(BOOTSTRAP_SPAN):
        idx = resampled(len(before), seed, n)
        shrink = 1 - after[idx].sum(1) / before[idx].sum(1).clamp(min=1e-12)
        return interval95(shrink)


def paired_difference_ci(
    before: torch.Tensor, a: torch.Tensor, b: torch.Tensor, seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float, float]:
    """Bootstrap 95% CI of ``(sum(b) - sum(a)) / sum(before)`` over resampled pairs: how much
    more of the gap ``a`` removes than ``b``, on the same held-out pairs."""
    with timed_span(BOOTSTRAP_SPAN):
        idx = resampled(len(before), seed, n)
        diff = (b[idx].sum(1) - a[idx].sum(1)) / before[idx].sum(1).clamp(min=1e-12)
        return interval95(diff)


#: what tells apart two effects acting on these parts of image formation, when the pairs at
#: hand cannot
SEPARATE_BY: dict[frozenset[str], str] = {
    frozenset({"geometry", "optics"}): "presses of one shape at several depths: the gel's "
    "geometry changes the contact's shape with depth, the optics only its colour",
    frozenset({"geometry", "camera"}): "the no-contact frame's texture against the sim's "
    "own, and flat presses: a lens blurs all it sees, the gel's geometry changes only where "
    "it is pressed",
    frozenset({"optics", "camera"}): "the no-contact frame and frames of a flat press: "
    "camera effects change them, the contact's optics do not",
    **{
        frozenset({"pose", other}): "a press at a marked point of the gel: it measures the "
        "depth's misregistration directly"
        for other in ("geometry", "optics", "camera")
    },
}
ANY_SHAPE = "more pairs, or contacts of other shapes and depths"


class FittedImages:
    """Each option's fitted held-out images with the selected effects (None when it draws
    at random), rendered once and only when asked."""

    def __init__(self, options: Options, selected: Selected, scene: PairScene) -> None:
        self.options, self.selected, self.scene = options, selected, scene
        self._images: dict[str, torch.Tensor | None] = {}

    def __call__(self, name: str) -> torch.Tensor | None:
        if name not in self._images:
            effects = {**self.selected, name: self.options[name][0]}
            random = any(get_candidate(n).stochastic for n in effects)
            self._images[name] = None if random else render(self.scene, effects)
        return self._images[name]

    def same(self, a: str, b: str) -> bool:
        """Both render, and differ by less than 8-bit rounding."""
        mine = self(a)
        theirs = self(b) if mine is not None else None
        return theirs is not None and float((theirs - mine).square().mean().sqrt()) < PIXEL_NOISE


def with_rivals(
    row: EffectFit,
    chosen: torch.Tensor,
    before: torch.Tensor,
    options: Options,
    threshold: float,
    seed: int,
    images: FittedImages | None = None,
) -> EffectFit:
    """``row`` with the rivals its held-out pairs cannot tell from it (see EffectFit): the
    paired CI of their difference reaches 0, or (``images`` given) their fitted images
    differ by less than 8-bit rounding."""
    rivals = []
    for name, (_, after) in options.items():
        if name == row.effect or float(before.mean() - after.mean()) < threshold:
            continue
        undecided = paired_difference_ci(before, chosen, after, seed)[0] <= 0
        if undecided or (images is not None and images.same(row.effect, name)):
            rivals.append(name)
    if not rivals:
        return row
    return replace(
        row, confusable_with=rivals, separate_by=separating_measurement(row.effect, rivals)
    )


def separating_measurement(effect: str, rivals: Sequence[str]) -> str:
    """What would tell ``effect`` from ``rivals`` when they act on two parts of image
    formation; else more pairs of other shapes and depths."""
    acts_on = {get_candidate(effect).acts_on} | {get_candidate(r).acts_on for r in rivals}
    hint = SEPARATE_BY.get(frozenset(acts_on), "") if len(acts_on) == 2 else ""
    return hint or ANY_SHAPE


@dataclass(frozen=True)
class DenoiseCheck:
    """On a noisy sim, whether an effect changes the image formation rather than only
    removing the sim's own noise: it must still remove the threshold's share of the gap
    when every draw's noise is brought back to the sim's level (``post``). An effect that
    adds camera noise cannot denoise."""

    held: tuple[PairScene, Target]
    post: PostDraw
    seed: int

    def passes(
        self, name: str, params: dict[str, float], selected: Selected, threshold: float
    ) -> bool:
        cand = get_candidate(name)
        if cand.acts_on == "camera" and cand.stochastic and not cand.latent_grid:
            return True
        with_it = {**selected, name: params}
        before, after = (
            model_gap(*self.held, e, self.seed, post=self.post) for e in (selected, with_it)
        )
        return float(before.mean() - after.mean()) >= threshold


@dataclass(frozen=True)
class Pick:
    """A round's pick (None: no effect passes the selection rule) and the effects passed
    over for removing only the sim's own noise."""

    row: EffectFit | None
    passed_over: tuple[str, ...] = ()


def pick_effect(
    options: Options,
    selected: Selected,
    current: torch.Tensor,
    threshold: float,
    scene: PairScene,
    rounding: float,
    seed: int,
    denoise: DenoiseCheck | None = None,
) -> Pick:
    """This round's effect: the one leaving least of the held-out gap, unless rivals the
    data cannot tell from it (``with_rivals``) that leave at most ``rounding`` more gap (what
    8-bit rounding alone makes) hold one with fewer fitted numbers; then the simplest of
    them (the one-standard-error rule: Hastie, Tibshirani & Friedman, *The Elements of
    Statistical Learning*, sec. 7.10). An effect that fails ``denoise`` is passed over for
    the next best. It passes when it removes ``threshold`` of the gap and its interval's
    lower end is above 0. Between a lens and a gel effect that both pass, the no-contact
    frame decides where it can read the lens (``with_frame``)."""
    images = FittedImages(options, selected, scene)
    frames = FrameCheck(scene, {n: p for n, (p, _) in options.items()}, selected, seed)
    passed_over: list[str] = []

    def row_of(name: str) -> EffectFit:
        params, after = options[name]
        row = EffectFit.measure(name, params, current, after, seed)
        return with_rivals(row, after, current, options, threshold, seed, images)

    def acceptable(row: EffectFit) -> bool:
        if row.gap_before - row.gap_after < threshold or row.ci_low <= 0:
            return False
        if denoise is None or denoise.passes(row.effect, row.params, selected, threshold):
            return True
        passed_over.append(row.effect)
        return False

    order = sorted(options, key=lambda n: float(options[n][1].mean()))
    best_row = None
    for name in order:
        row = row_of(name)
        if row.gap_before - row.gap_after < threshold or row.ci_low <= 0:
            break
        if acceptable(row):
            best_row = row
            break
    if best_row is None:
        return Pick(None, tuple(passed_over))
    simplest = _simplest(best_row, options, scene, rounding)
    if simplest != best_row.effect:
        alternative = row_of(simplest)
        if acceptable(alternative):
            best_row = alternative
    for name in order:
        if frames.prefers(name, best_row.effect):
            row = row_of(name)
            if acceptable(row):
                best_row = row
                break
    return Pick(with_frame(best_row, options, current, frames), tuple(passed_over))


def with_frame(
    row: EffectFit, options: Options, current: torch.Tensor, frames: FrameCheck
) -> EffectFit:
    """``row`` with its no-contact frame reading, and with the strong rivals across the lens /
    gel line it cannot be told from when the frame cannot read the lens: on the contacts
    alone a lens blur and a gel's spread both widen the trace, and the fit that widens
    more wins whatever widened it. Strong: removes ``STRONG_RIVAL`` of what is left."""
    reading = frames.reading(row.effect)
    if reading is not None:
        row = replace(row, no_contact=reading)
    now = float(current.mean())
    rivals, missing = [], []
    for name, (_, after) in options.items():
        if name == row.effect or name in row.confusable_with:
            continue
        if now - float(after.mean()) < STRONG_RIVAL * now:
            continue
        what = frames.cannot_read(row.effect, name)
        if what:
            rivals.append(name)
            missing.append(what)
    if not rivals:
        return row
    separate_by = "; ".join(dict.fromkeys([*missing, *filter(None, [row.separate_by])]))
    return replace(row, confusable_with=[*row.confusable_with, *rivals], separate_by=separate_by)


def _simplest(row: EffectFit, options: Options, scene: PairScene, rounding: float) -> str:
    """Of ``row``'s effect and its rivals within ``rounding`` of its gap (a rival that leaves
    more is a different explanation, however close its images), the one with the fewest
    fitted numbers; ``row``'s own on a tie."""
    within = float(options[row.effect][1].mean()) + rounding
    cost = {
        n: get_candidate(n).fitted_numbers(scene)
        for n in [row.effect, *row.confusable_with]
        if float(options[n][1].mean()) <= within
    }
    simplest = min(cost, key=lambda n: (cost[n], float(options[n][1].mean())))
    return simplest if cost[simplest] < cost[row.effect] else row.effect
