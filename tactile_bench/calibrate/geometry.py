"""The profile's gel geometry, refitted for the contact region by cross-validation.

The diagnosis selects and fits its effects for the whole frame on its own half / half split
of the fit pairs; a profile is judged where the frame changes, around the contact. So after
the selection every deterministic geometry effect that the diagnosis can search (selected
or not) is refitted here: each searched parameter in turn over a grid of its declared range
(and its current value), the one whose response lookup, fitted on the other folds, best
predicts the held-out fold's pixels within two contact radii (``press_grounding.
contact_mask``, the region ``ground`` scores). Folds interleave the fit pairs; every fold
fit comes from one pass over the pairs (``response_fit.pair_normal_equations``). An effect
left neutral is dropped: an unselected one is kept only where it beats the gel without it.
Only the fit pairs are read.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from functools import partial

import numpy as np
import torch
import torch.nn.functional as F

from tactile_bench.diagnose.candidates import CANDIDATES, Searched
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.scene import OVERSAMPLE
from tactile_bench.effects import EFFECT_ORDER, EFFECTS, EffectContext
from tactile_bench.sensor.press_grounding import contact_mask
from tactile_bench.sensor.response_fit import pair_normal_equations, predict_delta, solve_response

log = logging.getLogger("tactile_bench")

FOLDS = 4  # interleaved folds of the fit pairs
GRID = 13  # values tried across each searched parameter's declared range
FINE = 9  # values tried between the best grid value's neighbours
ROUNDS = 2  # passes over an effect's parameters (the second starts from the first's)
Effects = dict[str, dict[str, float]]


def profile_surface(
    depth: torch.Tensor, effects: Mapping[str, Mapping[str, float]], gel_mm: tuple[float, float]
) -> torch.Tensor:
    """The gel surface (N, 1, S, S) the profile renders the response on: ``depth`` (N, 1,
    S, S) at twice the size (bilinear, as the diagnosis oversamples), its deterministic
    geometry effects applied there, the positive part area-averaged back to S."""
    ctx = EffectContext(gel_mm[0], gel_mm[1], False)
    height = F.interpolate(depth.float(), scale_factor=OVERSAMPLE, mode="bilinear")
    for name in [n for n in EFFECT_ORDER if n in effects]:
        effect = EFFECTS[name]
        if effect.acts_on == "geometry" and not effect.stochastic:
            height = effect.apply(height, effect.validate(effects[name]), None, ctx)
    return F.avg_pool2d(height.clamp(min=0.0), OVERSAMPLE)


def refittable() -> list[str]:
    """The deterministic geometry effects the diagnosis can search, in rendering order."""
    return [
        name
        for name in EFFECT_ORDER
        if name in CANDIDATES
        and EFFECTS[name].acts_on == "geometry"
        and not EFFECTS[name].stochastic
    ]


def contact_cv_error(
    fit: DiagnosisPairs, effects: Mapping[str, Mapping[str, float]], folds: list[torch.Tensor]
) -> float:
    """Mean squared error (grey levels) within the contact region of each fold's pairs,
    rendered by the lookup fitted on the other folds under the gel geometry of ``effects``."""
    gel = (float(fit.gel_mm[0]), float(fit.gel_mm[1]))
    surface = profile_surface(fit.depth, effects, gel)
    delta = fit.real.float() - fit.background[None].float()
    xtx, xty = pair_normal_equations(surface, delta, gel)
    total_xtx, total_xty = xtx.sum(0), xty.sum(0)
    err, count = 0.0, 0
    for test in folds:
        weights = solve_response(total_xtx - xtx[test].sum(0), total_xty - xty[test].sum(0))
        pred = fit.background[None].float() + predict_delta(surface[test], weights, gel)
        inside = contact_mask(fit.depth[test]).expand_as(pred)
        err += float(((pred.clamp(0, 255) - fit.real[test].float())[inside] ** 2).sum())
        count += int(inside.sum())
    return err / max(count, 1)


def _search(
    score: Callable[[float], float], searched: Searched, current: float
) -> tuple[float, dict[float, float]]:
    """The value of one parameter that ``score`` likes best: ``GRID`` values across its range
    (the current value tried first, so that a tie keeps it), then ``FINE`` values between
    the best one's grid neighbours; every value tried with its score."""
    scores = {current: score(current)}
    for u in np.linspace(0.0, 1.0, GRID):
        value = searched.report(float(u))
        scores.setdefault(value, score(value))
    best = min(scores, key=scores.__getitem__)
    step = 1.0 / (GRID - 1)
    centre = searched.to_unit(best)
    for u in np.linspace(max(centre - step, 0.0), min(centre + step, 1.0), FINE):
        value = searched.report(float(u))
        if value not in scores:
            scores[value] = score(value)
    return min(scores, key=scores.__getitem__), scores


def _trial_error(
    fit: DiagnosisPairs,
    effects: Effects,
    name: str,
    params: dict[str, float],
    key: str,
    folds: list[torch.Tensor],
    value: float,
) -> float:
    """``contact_cv_error`` with ``name``'s parameter ``key`` set to ``value``."""
    return contact_cv_error(fit, {**effects, name: {**params, key: value}}, folds)


def _refit_effect(
    fit: DiagnosisPairs,
    effects: Effects,
    name: str,
    folds: list[torch.Tensor],
    tried: dict[str, dict[str, float]],
) -> dict[str, float]:
    """Every parameter of ``name`` (its current values, else neutral) searched in turn, for
    up to ``ROUNDS`` passes; what was tried goes into ``tried``."""
    cand, own = CANDIDATES[name], {p.name for p in EFFECTS[name].params}
    params = {k: float(v) for k, v in cand.full_params(effects.get(name, {})).items() if k in own}
    for round_ in range(ROUNDS):
        start = dict(params)
        for s in cand.searched:
            score = partial(_trial_error, fit, effects, name, dict(params), s.name, folds)
            params[s.name], scores = _search(score, s, params[s.name])
            tried[f"{name}.{s.name}.round{round_ + 1}"] = {
                f"{v:g}": round(e, 3) for v, e in sorted(scores.items())
            }
        if params == start:
            break
    return params


def refit_geometry(
    fit: DiagnosisPairs, effects: Mapping[str, Mapping[str, float]]
) -> tuple[Effects, dict[str, object]]:
    """``effects`` with their gel geometry refitted for the contact region (module
    docstring), and a record: the CV error before and after and every value tried."""
    out: Effects = {n: dict(p) for n, p in effects.items()}
    n_folds = min(FOLDS, len(fit))
    folds = [torch.arange(k, len(fit), n_folds, device=fit.depth.device) for k in range(n_folds)]
    before = contact_cv_error(fit, out, folds)
    record: dict[str, object] = {"folds": n_folds, "cv_contact_mse_before": round(before, 3)}
    tried: dict[str, dict[str, float]] = {}
    for name in refittable():
        out[name] = _refit_effect(fit, out, name, folds, tried)
        if EFFECTS[name].is_neutral(EFFECTS[name].validate(out[name])):
            out.pop(name)
        log.info("geometry: %s -> %s", name, out.get(name, "neutral (dropped)"))
    record["cv_contact_mse_after"] = round(contact_cv_error(fit, out, folds), 3)
    record["tried"] = tried
    return {n: out[n] for n in EFFECT_ORDER if n in out}, record
