"""Which effect causes the gap: fit every candidate, then greedy forward selection.

Every candidate of the catalogue (``candidates.CANDIDATES``) is fitted alone on the fit split
(``gapfit.fit_candidate``) and scored on the held-out split by the share of the gap it
removes (``singles``). Greedy forward selection then adds, round by round, the candidate
that removes most of what is left, refitted with the ones already chosen (see
``_worth_refitting``), while it removes
more than ``MIN_SHARE`` of the initial gap (once camera noise is selected: of the initial gap
less the noise's own floor, the part a model can remove) and the lower end of its bootstrap
95% CI (held-out pairs resampled) is above zero. With two or more selected, their differentiable
parameters are refitted jointly. ``unexplained`` is what is left, as a share of the initial
gap; above ``FLAG_UNEXPLAINED`` the residual is flagged: some cause outside the candidate
set (or an unfittable one) carries it. The selection is then re-run with the shallow presses
fitted and the deep ones held out (``stability``): an explanation that names another effect
there is flagged too, however small its residual. The diagnosis reads paired data only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch
from tqdm.auto import tqdm

from tactile_bench.diagnose.candidates import (
    DEFAULT_CANDIDATES,
    NOT_CANDIDATES,
    Base,
    _deterministic_geometry,
    get_candidate,
    lookup_for,
    make_base,
    render,
    sim_optics_report,
)
from tactile_bench.diagnose.gapfit import (
    GAP_METRIC,
    PostDraw,
    Target,
    fit_candidate,
    fit_jointly,
    is_stochastic,
    model_gap,
    rounding_gap,
)
from tactile_bench.diagnose.noise import FrameNoise, frame_noise
from tactile_bench.diagnose.paired import PairedData
from tactile_bench.diagnose.stability import Stability
from tactile_bench.diagnose.stability import check as check_stability
from tactile_bench.errors import TactileBenchError

MIN_SHARE = 0.02  # a selected effect removes at least this share of the initial gap
FLAG_UNEXPLAINED = 0.2  # residual share above which it is flagged
MAX_ROUNDS = 4
BOOTSTRAP = 500
# RMS of 8-bit rounding (1/sqrt(12) grey level): fitted images closer than this are the
# same image as far as 8-bit frames can show
PIXEL_NOISE = 1 / math.sqrt(12)
MAX_REFITS = 4  # candidates refitted with the selected ones each round, best singles first
SCREEN_SHARE = 0.25  # ... plus any whose single fit still removes this share of what is left
SCREEN_PAIRS = 64
NOISY_SIM = 0.5  # grey levels: sim frames noisier than this, frame to frame, are noisy


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
    # bootstrap 95% CI of (rival's gap - this one's) / gap_before reaches 0
    confusable_with: list[str] = field(default_factory=list)
    separate_by: str = ""  # what measurement would tell them apart

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class WhichResult:
    """Selected effects in order, every candidate alone, and the unexplained residual."""

    ranking: list[EffectFit]
    singles: list[EffectFit]
    unexplained: float
    residual_flagged: bool
    gap_metric: str
    gap_before: float = math.nan  # held-out gap of the plain sim
    gap_after: float = math.nan  # held-out gap with the selected set (jointly refitted)
    # part of gap_after no model can remove: the larger of the pairs' own noise against
    # itself (``noise``) and what the selected model leaves on its own draws
    gap_floor: float = 0.0
    noise: dict[str, list[float]] = field(default_factory=dict)  # per source, grey levels
    selected_params: dict[str, dict[str, float]] = field(default_factory=dict)
    # the optical-response lookup (F x 3 x 6, see sensor.response_fit) fitted on the fit
    # split under the selected geometry, when optical_response is selected: the table
    response_table: list | None = None
    candidates: list[str] = field(default_factory=list)
    not_candidates: dict[str, str] = field(default_factory=dict)  # left out, and why
    # the first line: the sim's own no-contact frame replaced by the measured one (given by
    # the data, nothing fitted); its shrink is its share of the plain sim's gap. None when
    # the sim was composited onto the measured frame (``background_note`` says so). The
    # ranking, ``gap_before`` and ``unexplained`` are on the gap left after it.
    background: EffectFit | None = None
    background_note: str = ""
    # the user's sim optics the geometry candidates re-render with (``sim_optics_model``):
    # which model, and each model's MSE on held-in sim images (the floor of geometry fits)
    sim_optics: dict[str, Any] = field(default_factory=dict)
    # on a noisy sim: effects that would have been selected only for removing the sim's own
    # frame-to-frame noise (``FrameNoise.topped_up``), set aside
    set_aside_as_denoising: list[str] = field(default_factory=list)
    # the selection re-run with the shallow presses fitted and the deep ones held out
    # (``stability.check``); None when not run
    stability: Stability | None = None

    @property
    def unstable(self) -> bool:
        """The depth split names first an effect the selection neither holds nor finds
        confusable: the explanation depends on which presses were fitted."""
        return self.stability is not None and not self.stability.agrees

    @property
    def flagged(self) -> bool:
        """Some cause outside the candidates is likely: a large residual, or an explanation
        that changes with the presses it was fitted on."""
        return self.residual_flagged or self.unstable

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ranking"] = [r.to_dict() for r in self.ranking]
        d["singles"] = [r.to_dict() for r in self.singles]
        d["background"] = self.background.to_dict() if self.background else None
        d["stability"] = self.stability.to_dict() if self.stability else None
        d["unstable"], d["flagged"] = self.unstable, self.flagged
        return d


def shrink_ci(
    before: torch.Tensor, after: torch.Tensor, seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float, float]:
    """Bootstrap 95% CI of ``1 - sum(after) / sum(before)`` over resampled pairs."""
    gen = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, len(before), (n, len(before)), generator=gen)
    shrink = 1 - after[idx].sum(1) / before[idx].sum(1).clamp(min=1e-12)
    lo, hi = torch.quantile(shrink, torch.tensor([0.025, 0.975])).tolist()
    return float(lo), float(hi)


def _row(
    name: str, params: dict[str, float], before: torch.Tensor, after: torch.Tensor, seed: int
) -> EffectFit:
    b, a = float(before.mean()), float(after.mean())
    shrink = (b - a) / b if b > 0 else 0.0
    lo, hi = shrink_ci(before, after, seed)
    # a percentile interval of a skewed ratio can miss its own estimate (degenerate data):
    # the reported interval always holds it
    return EffectFit(name, params, b, a, shrink, min(lo, shrink), max(hi, shrink))


#: what tells apart two effects acting on these parts of image formation, when the pairs at
#: hand cannot
_SEPARATE_BY: dict[frozenset[str], str] = {
    frozenset({"geometry", "optics"}): "presses of one shape at several depths: the gel's "
    "geometry changes the contact's shape with depth, the optics only its colour",
    frozenset({"geometry", "camera"}): "no-contact frames and flat presses: camera effects "
    "act on them, gel geometry does not",
    frozenset({"optics", "camera"}): "the no-contact frame and frames of a flat press: "
    "camera effects change them, the contact's optics do not",
    **{
        frozenset({"pose", other}): "a press at a marked point of the gel: it measures the "
        "depth's misregistration directly"
        for other in ("geometry", "optics", "camera")
    },
}


def paired_difference_ci(
    before: torch.Tensor, a: torch.Tensor, b: torch.Tensor, seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float, float]:
    """Bootstrap 95% CI of ``(sum(b) - sum(a)) / sum(before)`` over resampled pairs: how much
    more of the gap ``a`` removes than ``b``, on the same held-out pairs."""
    gen = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, len(before), (n, len(before)), generator=gen)
    diff = (b[idx].sum(1) - a[idx].sum(1)) / before[idx].sum(1).clamp(min=1e-12)
    lo, hi = torch.quantile(diff, torch.tensor([0.025, 0.975])).tolist()
    return float(lo), float(hi)


def _confusable(
    row: EffectFit,
    chosen: torch.Tensor,
    before: torch.Tensor,
    options: Mapping[str, tuple[dict[str, float], torch.Tensor]],
    threshold: float,
    seed: int,
    image_of: Callable[[str], torch.Tensor | None] | None = None,
) -> EffectFit:
    """``row`` with the rivals its held-out pairs cannot tell from it (see EffectFit): the
    paired CI of their difference reaches 0, or (``image_of``: each one's fitted held-out
    images, None when drawn at random) their images differ by less than 8-bit rounding."""

    def same_images(name: str) -> bool:  # rendered only when the interval cannot decide
        mine = image_of(row.effect) if image_of else None
        theirs = image_of(name) if image_of and mine is not None else None
        return theirs is not None and float((theirs - mine).square().mean().sqrt()) < PIXEL_NOISE

    rivals = []
    for name, (_, after) in options.items():
        if name == row.effect or float(before.mean() - after.mean()) < threshold:
            continue
        if paired_difference_ci(before, chosen, after, seed)[0] <= 0 or same_images(name):
            rivals.append(name)
    if not rivals:
        return row
    acts_on = {get_candidate(row.effect).acts_on} | {get_candidate(r).acts_on for r in rivals}
    hint = _SEPARATE_BY.get(frozenset(acts_on), "") if len(acts_on) == 2 else ""
    hint = hint or "more pairs, or contacts of other shapes and depths"
    return replace(row, confusable_with=rivals, separate_by=hint)


def _check_split(data: PairedData, idx: torch.Tensor, what: str) -> torch.Tensor:
    idx = torch.as_tensor(idx, dtype=torch.long).reshape(-1)
    if len(idx) < 2:
        raise TactileBenchError(f"explain_gap: the {what} split needs at least 2 pairs")
    if int(idx.min()) < 0 or int(idx.max()) >= len(data):
        raise TactileBenchError(f"explain_gap: {what} indices outside 0..{len(data) - 1}")
    return idx


def explain_gap(
    data: PairedData,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    candidates: Sequence[str] | None = None,
    seed: int = 0,
    progress: bool = True,
    stability: bool = True,
    max_rounds: int = MAX_ROUNDS,
) -> WhichResult:
    """Fit every candidate on ``fit_idx``, score it on ``held_idx``, select the set that
    explains the gap, and report what it leaves unexplained (see the module docstring);
    ``stability``: also re-run the selection across press depths (``stability.check``);
    ``max_rounds``: stop selecting after this many effects."""
    fit_idx = _check_split(data, fit_idx, "fit")
    held_idx = _check_split(data, held_idx, "held-out")
    names = list(DEFAULT_CANDIDATES if candidates is None else candidates)
    [get_candidate(n) for n in names]  # an unknown name is a one-line error before any fit
    fit, held = _splits(data, fit_idx, held_idx)
    (base_fit, target_fit), (base_held, target_held) = fit, held
    gap0 = model_gap(base_held, target_held, {}, seed)
    g0 = float(gap0.mean())
    pairs = data.subset(held_idx)
    noise = frame_noise(pairs.depth, pairs.sim, pairs.real, pairs.background, pairs.sim_background)
    background, background_note = _background_line(data, held_idx, target_held, gap0, seed)
    threshold = MIN_SHARE * g0

    fits = _fit_each(names, {}, fit, held, seed, progress)
    singles = sorted(
        (_row(n, p, gap0, g, seed) for n, (p, g) in fits.items()), key=lambda r: -r.shrink
    )
    noisy_sim = float(noise.sim.sqrt().max()) > NOISY_SIM
    useful, noise_like = _refit_pool(names, singles, g0, noisy_sim)
    n_screen = min(len(fit_idx), SCREEN_PAIRS)
    screen = (base_fit.subset(torch.arange(n_screen)), target_fit.subset(torch.arange(n_screen)))

    selected: dict[str, dict[str, float]] = {}
    ranking: list[EffectFit] = []
    current, options = gap0, fits
    rounding = rounding_gap(target_held, seed)
    set_aside: list[str] = []
    topped = noise.topped_up(seed) if noisy_sim else None

    def beyond_denoising(name: str) -> bool:
        params = options[name][0]
        if _beyond_denoising(name, params, selected, held, topped, threshold, seed):
            return True
        set_aside.append(name)
        return False

    for _ in range(max_rounds):
        if not options:
            break
        row = _pick(
            options, selected, current, threshold, base_held, rounding, seed, beyond_denoising
        )
        if row is None:
            break
        ranking.append(row)
        best, (params, after) = row.effect, options[row.effect]
        unmasked = is_stochastic({best: params}) and not is_stochastic(selected)
        selected[best] = params
        current = after
        if unmasked:
            # the share asked of an effect is of the gap a model can remove: a camera's own
            # randomness (the floor, as ``unexplained`` counts it) is not part of it
            threshold = MIN_SHARE * max(g0 - _own_randomness(base_held, selected, seed), 0.0)
        if float(current.mean()) < threshold:  # nothing left that could pass the threshold
            break
        rest = [n for n in useful if n not in selected]
        if not unmasked:  # the single fits were made against a gap the noise dominated
            kept = _worth_refitting(rest, fits, selected, screen)
            rest = kept + [n for n in rest if n in noise_like and n not in kept]
        options = _fit_each(rest, selected, fit, held, seed, progress)
    if len(selected) >= 2:
        selected, current = _joint_if_better(selected, current, fit, held, seed)
    result = _result(
        ranking,
        singles,
        selected,
        current,
        g0,
        names,
        (background, background_note),
        (base_fit, base_held),
        noise,
        seed,
    )
    result.set_aside_as_denoising = [n for n in dict.fromkeys(set_aside) if n not in selected]
    if stability:

        def rerun(fit_part: torch.Tensor, held_part: torch.Tensor) -> list[EffectFit]:
            # only what it names first is compared: later rounds would not change that
            return explain_gap(
                data,
                fit_part,
                held_part,
                names,
                seed,
                progress=False,
                stability=False,
                max_rounds=1,
            ).ranking

        result.stability = check_stability(ranking, data.depth, rerun)
    return result


def _splits(
    data: PairedData, fit_idx: torch.Tensor, held_idx: torch.Tensor
) -> tuple[tuple[Base, Target], tuple[Base, Target]]:
    """The fit and held-out splits as (sim side, real target); the response lookups are
    fitted on the fit split once and shared by both."""
    cache: dict[str, torch.Tensor] = {}
    base_fit = make_base(data, fit_idx, lookup_from=fit_idx, lookup_cache=cache)
    base_held = make_base(data, held_idx, lookup_from=fit_idx, lookup_cache=cache)
    base_fit.precompute(), base_held.precompute()  # once, before the fits take subsets
    return (base_fit, Target.of(data.real[fit_idx])), (base_held, Target.of(data.real[held_idx]))


def _refit_pool(
    names: Sequence[str], singles: Sequence[EffectFit], g0: float, noisy_sim: bool
) -> tuple[list[str], list[str]]:
    """The candidates refitted in later rounds, and which of them are there as camera noise.

    A candidate that alone removes nothing is not refitted; one below the threshold still is
    (screened first, ``_worth_refitting``): camera noise that dominates the first gap masks a
    deterministic effect's single share (an optical response under read noise of 13 grey
    levels: 0.2%) until the noise is modelled. On a noisy sim, per-frame camera noise stays
    in play whatever its single fit did: it removes nothing alone, but an effect that smooths
    the sim's own noise (a blur) leaves a texture only the noise restores (third renderer,
    blur under noise in sim and real: 0.258 unexplained without this refit, 0.000 with it).
    A noise-free sim does not ask for it: there the noise would only patch the texture of
    other misfits.
    """
    useful = [r.effect for r in singles if g0 - r.gap_after > 0]
    noise_like = [n for n in names if noisy_sim and _is_camera_noise(n) and n not in useful]
    return useful + noise_like, noise_like


def _beyond_denoising(
    name: str,
    params: Mapping[str, float],
    selected: Mapping[str, Mapping[str, float]],
    held: tuple[Base, Target],
    topped: PostDraw | None,
    threshold: float,
    seed: int,
) -> bool:
    """On a noisy sim (``topped``: the draws' noise brought back to the sim's level),
    ``name`` still removes the threshold's share: it changes the image formation, not only
    the sim's noise (third renderer, nothing planted, noise in sim and real: the response
    lookup was selected at 0.053 for replacing the noisy colour change)."""
    if topped is None or _is_camera_noise(name):  # it adds noise: it cannot denoise
        return True
    with_it = {**selected, name: params}
    before, after = (model_gap(*held, e, seed, post=topped) for e in (selected, with_it))
    return float(before.mean() - after.mean()) >= threshold


def _joint_if_better(
    selected: dict[str, dict[str, float]],
    current: torch.Tensor,
    fit: tuple[Base, Target],
    held: tuple[Base, Target],
    seed: int,
) -> tuple[dict[str, dict[str, float]], torch.Tensor]:
    """The selection refitted jointly, kept if it fits the fit split better (the held-out
    split only scores), with its held-out per-pair gap; else the selection as it was."""
    joint = fit_jointly(selected, *fit, seed=seed)
    fit_gaps = [model_gap(*fit, e, seed).mean() for e in (joint, selected)]
    if float(fit_gaps[0]) < float(fit_gaps[1]):
        return joint, model_gap(*held, joint, seed)
    return selected, current


def _result(
    ranking: list[EffectFit],
    singles: list[EffectFit],
    selected: dict[str, dict[str, float]],
    current: torch.Tensor,
    g0: float,
    names: list[str],
    background_line: tuple[EffectFit | None, str],
    bases: tuple[Base, Base],
    noise: FrameNoise,
    seed: int,
) -> WhichResult:
    """The "which" answer: what the selection leaves above the floor no model can remove
    (the pairs' noise, or the model's own randomness if larger), as a share of the first
    gap, and the fitted response table when the response is selected."""
    (background, background_note), (base_fit, base_held) = background_line, bases
    clean = render(base_held, selected, stochastic=False)
    floor = max(_own_randomness(base_held, selected, seed), float(noise.floor(clean).mean()))
    floor = min(max(floor, 0.0), float(current.mean()))
    unexplained = (float(current.mean()) - floor) / (g0 - floor) if g0 > floor else 0.0
    table = None
    if "optical_response" in selected:
        table = lookup_for(base_fit, _deterministic_geometry(selected)).round(decimals=3).tolist()
    return WhichResult(
        ranking=ranking,
        singles=singles,
        unexplained=unexplained,
        residual_flagged=unexplained > FLAG_UNEXPLAINED,
        gap_metric=GAP_METRIC,
        gap_before=g0,
        gap_after=float(current.mean()),
        gap_floor=floor,
        noise=noise.to_dict(),
        selected_params={k: dict(v) for k, v in selected.items()},
        response_table=table,
        candidates=names,
        not_candidates={k: v for k, v in NOT_CANDIDATES.items() if k not in names},
        background=background,
        background_note=background_note,
        sim_optics=sim_optics_report(base_fit),
    )


def _fit_each(
    names: Sequence[str],
    prior: Mapping[str, Mapping[str, float]],
    fit: tuple[Base, Target],
    held: tuple[Base, Target],
    seed: int,
    progress: bool,
) -> dict[str, tuple[dict[str, float], torch.Tensor]]:
    """Each of ``names`` fitted on ``fit`` with ``prior`` in place: its parameters and the
    held-out per-pair gap of ``prior`` + it."""
    out: dict[str, tuple[dict[str, float], torch.Tensor]] = {}
    desc = "refit with selected" if prior else "fit candidates"
    bar = tqdm(names, desc=desc, unit="effect", disable=not progress or not names)
    for name in bar:
        bar.set_postfix_str(name)
        params = fit_candidate(name, *fit, prior=prior or None, seed=seed)
        out[name] = (params, model_gap(*held, {**prior, name: params}, seed))
    return out


def _is_camera_noise(name: str) -> bool:
    """A candidate that draws each frame's camera noise anew."""
    cand = get_candidate(name)
    return cand.acts_on == "camera" and cand.stochastic and not cand.latent_grid


def _own_randomness(base: Base, selected: Mapping[str, Mapping[str, float]], seed: int) -> float:
    """The gap the ``selected`` model leaves on data drawn from itself (0 when it draws
    nothing): its own randomness, which no diagnosis can remove, so it is not counted as
    unexplained."""
    if not is_stochastic(selected):
        return 0.0
    pseudo = render(base, selected, torch.Generator().manual_seed(seed + 99))
    return float(model_gap(base, Target.of(pseudo), selected, seed).mean())


def _pick(
    options: Mapping[str, tuple[dict[str, float], torch.Tensor]],
    selected: Mapping[str, Mapping[str, float]],
    current: torch.Tensor,
    threshold: float,
    base: Base,
    rounding: float,
    seed: int,
    real_change: Callable[[str], bool] = lambda name: True,
) -> EffectFit | None:
    """This round's effect: the one leaving least of the held-out gap, unless rivals the
    data cannot tell from it (``_confusable``) that leave at most ``rounding`` more gap (what
    8-bit rounding alone makes) hold one with fewer fitted numbers; then the simplest of
    them (the data do not ask for the extra freedom: Hastie, Tibshirani & Friedman, *The
    Elements of Statistical Learning*, sec. 7.10, the one-standard-error rule). An effect
    that fails ``real_change`` is passed over for the next best. None when no effect
    passes the selection rule."""
    images: dict[str, torch.Tensor | None] = {}

    def image_of(name: str) -> torch.Tensor | None:
        if name not in images:
            effects = {**selected, name: options[name][0]}
            images[name] = (
                None if any(get_candidate(n).stochastic for n in effects) else render(base, effects)
            )
        return images[name]

    def row_of(name: str) -> EffectFit:
        params, after = options[name]
        row = _row(name, params, current, after, seed)
        return _confusable(row, after, current, options, threshold, seed, image_of)

    def passes(row: EffectFit) -> bool:
        return row.gap_before - row.gap_after >= threshold and row.ci_low > 0

    for best in sorted(options, key=lambda n: float(options[n][1].mean())):
        row = row_of(best)
        if not passes(row):
            return None
        if real_change(best):
            break
    else:
        return None
    # a rival that leaves more than rounding's worth of gap over the best is a different
    # explanation, however close its images: only the others compete on simplicity
    within = float(options[best][1].mean()) + rounding
    cost = {
        n: get_candidate(n).fitted_numbers(base)
        for n in [best, *row.confusable_with]
        if float(options[n][1].mean()) <= within
    }
    simplest = min(cost, key=lambda n: (cost[n], float(options[n][1].mean())))
    if cost[simplest] < cost[best]:
        alternative = row_of(simplest)
        if passes(alternative) and real_change(simplest):
            return alternative
    return row


BACKGROUND_LINE = "measured_background"


def _background_line(
    data: PairedData, held_idx: torch.Tensor, target: Target, gap: torch.Tensor, seed: int
) -> tuple[EffectFit | None, str]:
    """The background correction's row (its share of the plain sim's held-out gap), or
    None with the reason when there is nothing to correct."""
    if data.sim_background is None:
        return None, "the sim was composited onto the measured no-contact frame: no correction"
    if torch.equal(data.sim_background.float(), data.background.float()):
        return None, "the sim's no-contact frame is the measured one: no correction"
    plain = make_base(data, held_idx, onto_measured=False)
    before = model_gap(plain, target, {}, seed)
    row = _row(BACKGROUND_LINE, {}, before, gap, seed)
    note = "the sim's own no-contact frame replaced by the measured one (data, nothing fitted)"
    return row, note


def _worth_refitting(
    names: list[str],
    fits: Mapping[str, tuple[dict[str, float], torch.Tensor]],
    selected: Mapping[str, Mapping[str, float]],
    screen: tuple[Base, Target],
) -> list[str]:
    """Candidates to refit with ``selected`` (a refit costs as much as a first fit): the
    ``MAX_REFITS`` that did best alone, and any whose single fit, added as it is, still
    removes ``SCREEN_SHARE`` of what is left on the fit split (a weak effect of its own,
    such as a codec under a blur, that the single shrinks rank low)."""
    base, target = screen
    now = float(model_gap(base, target, selected).mean())
    keep = names[:MAX_REFITS]
    for name in names[MAX_REFITS:]:
        trial = float(model_gap(base, target, {**selected, name: fits[name][0]}).mean())
        if now - trial >= SCREEN_SHARE * now:
            keep.append(name)
    return keep


def apply_effects(
    data: PairedData,
    effects: Mapping[str, Mapping[str, float]],
    idx: torch.Tensor | None = None,
    seed: int = 0,
    fit_idx: torch.Tensor | None = None,
) -> torch.Tensor:
    """Sim images (N, 3, S, S), 0..255, of the pairs at ``idx`` with ``effects`` added
    (parameters as ``EffectFit.params``; the rest neutral); seeded for stochastic effects.
    ``fit_idx``: the fit split, which ``optical_response``'s lookup is fitted on."""
    fit = None if fit_idx is None else torch.as_tensor(fit_idx, dtype=torch.long)
    base = make_base(
        data, None if idx is None else torch.as_tensor(idx, dtype=torch.long), lookup_from=fit
    )
    with torch.no_grad():
        return render(base, effects, torch.Generator().manual_seed(seed))
