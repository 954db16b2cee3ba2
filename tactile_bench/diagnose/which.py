"""Which effect causes the gap: fit every candidate, then greedy forward selection.

``explain_gap`` runs these steps, each a function below:

1. ``_gap_problem``: the fit and held-out splits, the plain sim's held-out gap (after the
   measured background replaces the sim's, ``_background_line``), the pairs' own noise;
2. ``_fit_singles``: every candidate fitted alone on the fit split, scored on the held-out one;
3. ``_select``: greedy forward selection, round by round the effect that removes most of what
   is left (``ranking.pick_effect``), refitted with the ones already chosen, while it removes
   ``MIN_SHARE`` of the initial gap (of that gap less the model's own randomness once camera
   noise is in) and its bootstrap interval stays above 0;
4. ``_joint_if_better``: the selection's differentiable parameters refitted together;
   ``_swapped_rivals``: a strong rival put in place of each selected effect, the others
   kept: one that explains as much there is confusable with it (a noise that masked it in
   the round the effect was picked in is modelled by then);
5. ``_answer``: what is left above the floor no model can remove, as a share of the initial
   gap (``unexplained``, flagged above ``FLAG_UNEXPLAINED``);
6. ``_coalition_gaps``: every subset of the selection refitted on its own, for each effect's
   Shapley share of the explained gap (``shapley``), which does not depend on the order the
   greedy selection added them in;
7. ``_depth_split_check``: the first round re-run with the shallow presses fitted and the deep
   ones held out (``stability``): an explanation that names another effect there is flagged.

The diagnosis reads paired data only.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from typing import Any

import torch
from tqdm.auto import tqdm

from tactile_bench.diagnose import breakdown
from tactile_bench.diagnose.candidates import DEFAULT_CANDIDATES, NOT_CANDIDATES, get_candidate
from tactile_bench.diagnose.gapfit import (
    GAP_METRIC,
    Target,
    fit_candidate,
    fit_jointly,
    is_stochastic,
    model_gap,
    rounding_gap,
)
from tactile_bench.diagnose.no_contact import MISSING
from tactile_bench.diagnose.noise import FrameNoise, frame_noise
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.ranking import (
    DenoiseCheck,
    EffectFit,
    Options,
    paired_difference_ci,
    pick_effect,
    separating_measurement,
)
from tactile_bench.diagnose.scene import PairScene, fit_reference, make_scene
from tactile_bench.diagnose.shapley import ShapleyShare, shapley_shares
from tactile_bench.diagnose.simulate import deterministic_geometry, lookup_for, render
from tactile_bench.diagnose.stability import Stability
from tactile_bench.diagnose.stability import check as check_stability
from tactile_bench.diagnose.workers import map_fits
from tactile_bench.effects import EFFECT_ORDER
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.timing import timed_span

MIN_SHARE = 0.02  # a selected effect removes at least this share of the initial gap
FLAG_UNEXPLAINED = 0.2  # residual share above which it is flagged
MAX_ROUNDS = 4
MAX_REFITS = 4  # candidates refitted with the selected ones each round, best singles first
SCREEN_SHARE = 0.25  # ... plus any whose single fit still removes this share of what is left
SCREEN_PAIRS = 64
SWAP_RIVALS = 2  # the best single fits outside the selection tried in place of each effect
NOISY_SIM = 0.5  # grey levels: sim frames noisier than this, frame to frame, are noisy
BACKGROUND_LINE = "measured_background"
Split = tuple[PairScene, Target]


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
    # the user's sim optics the geometry candidates re-render with: which model, and each
    # model's MSE on held-in sim images (the floor of geometry fits)
    sim_optics: dict[str, Any] = field(default_factory=dict)
    # on a noisy sim: effects passed over for only removing the sim's own noise
    set_aside_as_denoising: list[str] = field(default_factory=list)
    # the first round re-run on the depth split; None when not run
    stability: Stability | None = None
    # each selected effect's Shapley share of the initial held-out gap, whatever the order
    shapley: list[ShapleyShare] = field(default_factory=list)

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
        d["shapley"] = [s.to_dict() for s in self.shapley]
        d["unstable"], d["flagged"] = self.unstable, self.flagged
        return d


@dataclass(frozen=True)
class GapProblem:
    """What every step reads: the fit and held-out splits, the screening pairs, the plain
    sim's held-out gap per pair, the pairs' own noise and the gap 8-bit rounding makes."""

    fit: Split
    held: Split
    screen: Split
    gap0: torch.Tensor
    noise: FrameNoise
    rounding: float
    seed: int
    spans: breakdown.FitSpans = breakdown.MAIN_FIT  # the timed spans of this run of the selection

    @property
    def g0(self) -> float:
        return float(self.gap0.mean())

    @property
    def noisy_sim(self) -> bool:
        return float(self.noise.sim.sqrt().max()) > NOISY_SIM


@dataclass(frozen=True)
class Round:
    """Where the selection stands: the effects chosen (their parameters and rows), the
    held-out per-pair gap they leave, each remaining candidate refitted with them, the share
    an effect must remove, and the effects passed over for denoising."""

    selected: dict[str, dict[str, float]]
    ranking: list[EffectFit]
    current: torch.Tensor
    options: Options
    threshold: float
    set_aside: tuple[str, ...] = ()


def explain_gap(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    candidates: Sequence[str] | None = None,
    seed: int = 0,
    progress: bool = True,
    stability: bool = True,
    max_rounds: int = MAX_ROUNDS,
    attribution: bool = True,
) -> WhichResult:
    """Fit every candidate on ``fit_idx``, score it on ``held_idx``, select the set that
    explains the gap, and report what it leaves unexplained (module docstring);
    ``stability``: also re-run the first round across press depths; ``max_rounds``: stop
    selecting after this many effects; ``attribution``: also the swapped rivals and the
    Shapley shares (what a reader of the answer needs; a simulator built on the selection
    does not)."""
    fit_idx = _check_split(data, fit_idx, "fit")
    held_idx = _check_split(data, held_idx, "held-out")
    names = _candidate_names(candidates)
    problem = _gap_problem(data, fit_idx, held_idx, seed)
    singles, fits = _fit_singles(problem, names, progress)
    with timed_span(problem.spans.select):
        chosen = _select(problem, names, singles, fits, max_rounds, progress)
    with timed_span(breakdown.JOINT_REFIT):
        selected, current = _joint_if_better(problem, chosen.selected, chosen.current)
    if attribution:
        with timed_span(breakdown.SWAPPED_RIVALS):
            ranking = _swapped_rivals(problem, singles, chosen.ranking, current)
        chosen = replace(chosen, ranking=ranking)
    with timed_span(breakdown.ANSWER):
        result = _answer(problem, names, singles, chosen, selected, current)
    with timed_span(breakdown.BACKGROUND):
        result.background, result.background_note = _background_line(data, held_idx, problem)
    if attribution:
        with timed_span(breakdown.SHAPLEY_COALITIONS):
            gaps = _coalition_gaps(problem, fits, selected, current)
        result.shapley = shapley_shares(list(selected), gaps, problem.seed)
    if stability:
        with timed_span(breakdown.DEPTH_SPLIT):
            result.stability = _depth_split_check(data, names, chosen.ranking, seed)
    return result


def _check_split(data: DiagnosisPairs, idx: torch.Tensor, what: str) -> torch.Tensor:
    idx = torch.as_tensor(idx, dtype=torch.long).reshape(-1)
    if len(idx) < 2:
        raise TactileBenchError(f"explain_gap: the {what} split needs at least 2 pairs")
    if int(idx.min()) < 0 or int(idx.max()) >= len(data):
        raise TactileBenchError(f"explain_gap: {what} indices outside 0..{len(data) - 1}")
    return idx


def _candidate_names(candidates: Sequence[str] | None) -> list[str]:
    """The candidates to fit; an unknown name is a one-line error before any fit."""
    names = list(DEFAULT_CANDIDATES if candidates is None else candidates)
    for name in names:
        get_candidate(name)
    return names


def _gap_problem(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    seed: int,
    timed: breakdown.FitSpans = breakdown.MAIN_FIT,
) -> GapProblem:
    """The splits as (scene, real target), sharing the fit split's reference, and what the
    held-out pairs measure before any effect; ``timed``: the spans this run is timed in."""
    with timed_span(timed.setup):
        reference = fit_reference(data, fit_idx)
        fit = (make_scene(data, fit_idx, reference).precompute(), Target.of(data.real[fit_idx]))
        held = (make_scene(data, held_idx, reference).precompute(), Target.of(data.real[held_idx]))
        n_screen = torch.arange(min(len(fit_idx), SCREEN_PAIRS), device=fit_idx.device)
        pairs = data.subset(held_idx)
        return GapProblem(
            fit=fit,
            held=held,
            screen=(fit[0].subset(n_screen), fit[1].subset(n_screen)),
            gap0=model_gap(*held, {}, seed),
            noise=frame_noise(
                pairs.depth, pairs.sim, pairs.real, pairs.background, pairs.sim_background
            ),
            rounding=rounding_gap(held[1], seed),
            seed=seed,
            spans=timed,
        )


def _fit_singles(
    problem: GapProblem, names: Sequence[str], progress: bool
) -> tuple[list[EffectFit], Options]:
    """Every candidate fitted alone: rows best first, and each one's fit and held-out gap."""
    fits = _fit_each(problem, names, {}, progress)
    rows = (EffectFit.measure(n, p, problem.gap0, g, problem.seed) for n, (p, g) in fits.items())
    return sorted(rows, key=lambda r: -r.shrink), fits


def _fit_each(
    problem: GapProblem,
    names: Sequence[str],
    prior: Mapping[str, Mapping[str, float]],
    progress: bool,
) -> dict[str, tuple[dict[str, float], torch.Tensor]]:
    """Each of ``names`` fitted on the fit split with ``prior`` in place: its parameters and
    the held-out per-pair gap of ``prior`` + it."""
    desc = "refit with selected" if prior else "fit candidates"
    bar = tqdm(total=len(names), desc=desc, unit="effect", disable=not progress or not names)

    def done(i: int) -> None:
        bar.set_postfix_str(names[i])
        bar.update()

    with bar:
        calls = [(problem, name, prior) for name in names]
        fits = map_fits(_fit_one, calls, problem.fit[0].reference, done)
    return dict(zip(names, fits, strict=True))


def _fit_one(
    problem: GapProblem, name: str, prior: Mapping[str, Mapping[str, float]]
) -> tuple[dict[str, float], torch.Tensor]:
    """``name`` fitted with ``prior`` in place: its parameters and held-out per-pair gap
    (a module-level function: ``map_fits`` may run it in a worker process)."""
    with timed_span(problem.spans.refit if prior else problem.spans.candidate_fit):
        params = fit_candidate(name, *problem.fit, prior=prior or None, seed=problem.seed)
        return params, model_gap(*problem.held, {**prior, name: params}, problem.seed)


def _select(
    problem: GapProblem,
    names: Sequence[str],
    singles: Sequence[EffectFit],
    fits: Options,
    max_rounds: int,
    progress: bool,
) -> Round:
    """Greedy forward selection from the single fits (module docstring, step 3)."""
    pool, noise_like = _refit_pool(problem, names, singles)
    denoise = None
    if problem.noisy_sim:
        denoise = DenoiseCheck(problem.held, problem.noise.topped_up(problem.seed), problem.seed)
    state = Round({}, [], problem.gap0, fits, MIN_SHARE * problem.g0)
    for round_no in range(1, max_rounds + 1):
        if not state.options:
            break
        pick = pick_effect(
            state.options,
            state.selected,
            state.current,
            state.threshold,
            problem.held[0],
            problem.rounding,
            problem.seed,
            denoise,
        )
        state = replace(state, set_aside=state.set_aside + pick.passed_over)
        if pick.row is None:
            break
        unmasked = _unmasks_noise(state.selected, pick.row)
        state = _add(problem, state, pick.row, unmasked)
        if float(state.current.mean()) < state.threshold:  # nothing left that could pass
            break
        if round_no == max_rounds:  # no round left to read the refits
            break
        if unmasked:  # every single fit was judged against a gap the noise dominated
            rest = [n for n in names if n not in state.selected]
        else:
            rest = [n for n in pool if n not in state.selected]
            kept = _worth_refitting(problem, rest, fits, state.selected)
            rest = kept + [n for n in rest if n in noise_like and n not in kept]
        state = replace(state, options=_fit_each(problem, rest, state.selected, progress))
    return state


def _unmasks_noise(selected: Mapping[str, Mapping[str, float]], row: EffectFit) -> bool:
    """The first effect that draws camera randomness: the single fits were made against a
    gap its noise dominated, and the threshold changes (``_add``)."""
    return is_stochastic({row.effect: row.params}) and not is_stochastic(selected)


def _add(problem: GapProblem, state: Round, row: EffectFit, unmasked: bool) -> Round:
    """``state`` with ``row``'s effect selected. When it unmasks camera noise, the share
    asked of later effects is of the gap a model can remove: the initial gap less the
    model's own randomness (the floor, as ``unexplained`` counts it)."""
    params, after = state.options[row.effect]
    selected = {**state.selected, row.effect: params}
    threshold = state.threshold
    if unmasked:
        removable = problem.g0 - _own_randomness(problem.held[0], selected, problem.seed)
        threshold = MIN_SHARE * max(removable, 0.0)
    return replace(
        state,
        selected=selected,
        ranking=[*state.ranking, row],
        current=after,
        threshold=threshold,
    )


def _refit_pool(
    problem: GapProblem, names: Sequence[str], singles: Sequence[EffectFit]
) -> tuple[list[str], list[str]]:
    """The candidates refitted in later rounds, and which of them are there as camera noise.

    A candidate that alone removes nothing is not refitted; one below the threshold still is
    (screened first, ``_worth_refitting``): camera noise that dominates the first gap masks a
    deterministic effect's single share until the noise is modelled. In the round after the
    noise is selected every candidate is refitted (``_select``): a lens blur under noise
    removes nothing alone, its texture lost in the noise's. On a noisy sim,
    per-frame camera noise stays in play whatever its single fit did: it removes nothing
    alone, but an effect that smooths the sim's own noise (a blur) leaves a texture only the
    noise restores. A noise-free sim does not ask for it: there the noise would only patch
    the texture of other misfits.
    """
    useful = [r.effect for r in singles if problem.g0 - r.gap_after > 0]
    noise_like = [n for n in names if problem.noisy_sim and _is_camera_noise(n) and n not in useful]
    return useful + noise_like, noise_like


def _worth_refitting(
    problem: GapProblem,
    names: list[str],
    fits: Options,
    selected: Mapping[str, Mapping[str, float]],
) -> list[str]:
    """Candidates to refit with ``selected`` (a refit costs as much as a first fit): the
    ``MAX_REFITS`` that did best alone, and any whose single fit, added as it is, still
    removes ``SCREEN_SHARE`` of what is left on the screening pairs (a weak effect of its
    own, such as a codec under a blur, that the single shrinks rank low)."""
    now = float(model_gap(*problem.screen, selected).mean())
    keep = names[:MAX_REFITS]
    for name in names[MAX_REFITS:]:
        trial = float(model_gap(*problem.screen, {**selected, name: fits[name][0]}).mean())
        if now - trial >= SCREEN_SHARE * now:
            keep.append(name)
    return keep


def _is_camera_noise(name: str) -> bool:
    """A candidate that draws each frame's camera noise anew."""
    cand = get_candidate(name)
    return cand.acts_on == "camera" and cand.stochastic and not cand.latent_grid


def _own_randomness(
    scene: PairScene, selected: Mapping[str, Mapping[str, float]], seed: int
) -> float:
    """The gap the ``selected`` model leaves on data drawn from itself (0 when it draws
    nothing): its own randomness, which no diagnosis can remove."""
    if not is_stochastic(selected):
        return 0.0
    pseudo = render(scene, selected, torch.Generator().manual_seed(seed + 99))
    return float(model_gap(scene, Target.of(pseudo), selected, seed).mean())


def _joint_if_better(
    problem: GapProblem, selected: dict[str, dict[str, float]], current: torch.Tensor
) -> tuple[dict[str, dict[str, float]], torch.Tensor]:
    """Two or more selected: refitted jointly, kept if that fits the fit split better (the
    held-out split only scores), with its held-out per-pair gap; else as they were."""
    if len(selected) < 2:
        return selected, current
    joint = fit_jointly(selected, *problem.fit, seed=problem.seed)
    fit_gaps = [model_gap(*problem.fit, e, problem.seed).mean() for e in (joint, selected)]
    if float(fit_gaps[0]) < float(fit_gaps[1]):
        return joint, model_gap(*problem.held, joint, problem.seed)
    return selected, current


def _swapped_rivals(
    problem: GapProblem,
    singles: Sequence[EffectFit],
    ranking: list[EffectFit],
    current: torch.Tensor,
) -> list[EffectFit]:
    """The ranking with, for each selected effect, the rivals that explain as much in its
    place: the selection with the rival instead of it refitted on the fit split
    (``_refit_coalition``), its held-out gap not worse than the selection's by the paired
    bootstrap 95% interval. Tried for the ``SWAP_RIVALS`` best single fits outside the
    selection that alone remove ``SCREEN_SHARE`` of the gap, when two or more are selected
    (one alone was compared with every rival in its round)."""
    chosen = [row.effect for row in ranking]
    if len(chosen) < 2:
        return ranking
    strong = [r.effect for r in singles if r.effect not in chosen and r.shrink >= SCREEN_SHARE]
    tries = [
        (row.effect, rival)
        for row in ranking
        for rival in [n for n in strong if n not in row.confusable_with][:SWAP_RIVALS]
    ]
    calls = [(problem, [*(n for n in chosen if n != e), rival]) for e, rival in tries]
    gaps = map_fits(_refit_coalition, calls, problem.fit[0].reference)  # the fits side by side
    as_good = [paired_difference_ci(problem.gap0, current, g, problem.seed)[0] <= 0 for g in gaps]
    out = []
    for row in ranking:
        found = [r for (e, r), ok in zip(tries, as_good, strict=True) if ok and e == row.effect]
        if found:
            rivals = [*row.confusable_with, *found]
            # what the round named missing of the no-contact frame stays
            missing = [h for h in row.separate_by.split("; ") if h in MISSING.values()]
            hints = [*missing, separating_measurement(row.effect, rivals)]
            row = replace(row, confusable_with=rivals, separate_by="; ".join(hints))
        out.append(row)
    return out


def _answer(
    problem: GapProblem,
    names: list[str],
    singles: list[EffectFit],
    chosen: Round,
    selected: dict[str, dict[str, float]],
    current: torch.Tensor,
) -> WhichResult:
    """What the selection leaves above the floor no model can remove (the pairs' noise, or
    the model's own randomness if larger), as a share of the first gap; the fitted
    response table when the response is selected."""
    held_scene, fit_scene = problem.held[0], problem.fit[0]
    clean = render(held_scene, selected, stochastic=False)
    floor = max(
        _own_randomness(held_scene, selected, problem.seed),
        float(problem.noise.floor(clean).mean()),
    )
    floor = min(max(floor, 0.0), float(current.mean()))
    g0 = problem.g0
    unexplained = (float(current.mean()) - floor) / (g0 - floor) if g0 > floor else 0.0
    table = None
    if "optical_response" in selected:
        lookup = lookup_for(fit_scene, deterministic_geometry(selected))
        table = lookup.round(decimals=3).tolist()
    reference = fit_scene.reference
    return WhichResult(
        ranking=chosen.ranking,
        singles=singles,
        unexplained=unexplained,
        residual_flagged=unexplained > FLAG_UNEXPLAINED,
        gap_metric=GAP_METRIC,
        gap_before=g0,
        gap_after=float(current.mean()),
        gap_floor=floor,
        noise=problem.noise.to_dict(),
        selected_params={k: dict(v) for k, v in selected.items()},
        response_table=table,
        candidates=names,
        not_candidates={k: v for k, v in NOT_CANDIDATES.items() if k not in names},
        sim_optics=reference.sim_optics.report() if reference else {},
        set_aside_as_denoising=[n for n in dict.fromkeys(chosen.set_aside) if n not in selected],
    )


def _coalition_gaps(
    problem: GapProblem,
    fits: Options,
    selected: dict[str, dict[str, float]],
    current: torch.Tensor,
) -> dict[frozenset[str], torch.Tensor]:
    """The held-out gap per pair of every subset of ``selected``: none is the plain sim, all
    is the selection (``current``), a single effect its single fit; the others refitted on
    the fit split on their own (``_refit_coalition``)."""
    names = sorted(selected)
    gaps = {frozenset(): problem.gap0, frozenset(names): current}
    gaps.update({frozenset([name]): fits[name][1] for name in names if len(names) > 1})
    refitted = [c for k in range(2, len(names)) for c in itertools.combinations(names, k)]
    refits = map_fits(_refit_coalition, [(problem, c) for c in refitted], problem.fit[0].reference)
    gaps.update({frozenset(c): g for c, g in zip(refitted, refits, strict=True)})
    return gaps


def _refit_coalition(problem: GapProblem, names: Sequence[str]) -> torch.Tensor:
    """Effects fitted one after the other in catalogue order (whatever order they were
    selected in), then jointly if that fits better: their held-out gap per pair."""
    effects: dict[str, dict[str, float]] = {}
    for name in [n for n in EFFECT_ORDER if n in names]:
        effects[name] = fit_candidate(name, *problem.fit, prior=effects or None, seed=problem.seed)
    _, gap = _joint_if_better(problem, effects, model_gap(*problem.held, effects, problem.seed))
    return gap


def _background_line(
    data: DiagnosisPairs, held_idx: torch.Tensor, problem: GapProblem
) -> tuple[EffectFit | None, str]:
    """The background correction's row (its share of the plain sim's held-out gap), or
    None with the reason when there is nothing to correct."""
    if data.sim_background is None:
        return None, "the sim was composited onto the measured no-contact frame: no correction"
    if torch.equal(data.sim_background.float(), data.background.float()):
        return None, "the sim's no-contact frame is the measured one: no correction"
    plain = make_scene(data, held_idx, onto_measured=False)
    before = model_gap(plain, problem.held[1], {}, problem.seed)
    row = EffectFit.measure(BACKGROUND_LINE, {}, before, problem.gap0, problem.seed)
    note = "the sim's own no-contact frame replaced by the measured one (data, nothing fitted)"
    return row, note


def first_round(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    names: Sequence[str],
    seed: int,
) -> list[EffectFit]:
    """The selection's first round on these splits: the effect it names first, if any
    (timed in the depth split's spans: the check is its one caller in the diagnosis)."""
    problem = _gap_problem(data, fit_idx, held_idx, seed, breakdown.DEPTH_SPLIT_FIT)
    singles, fits = _fit_singles(problem, names, progress=False)
    with timed_span(problem.spans.select):
        return _select(problem, names, singles, fits, max_rounds=1, progress=False).ranking


def _depth_split_check(
    data: DiagnosisPairs, names: Sequence[str], ranking: list[EffectFit], seed: int
) -> Stability | None:
    """The first round with the shallow presses fitted and the deep ones held out, against
    the selection (``stability.check``)."""
    rerun = partial(first_round, data, names=names, seed=seed)
    return check_stability(ranking, data.depth, rerun)
