"""The gap measure and the fit of a candidate's parameters to it.

Gap between a candidate sim' and the real image of each pair, grey level^2 (0..255 scale),
``GAP_METRIC`` in words:

- **structure**: MSE of the images low-passed to about 1 px (2 x 2 area average, then a
  Gaussian of sigma 0.5 px at half size);
- **texture**: the squared difference of the local gradient strength along and across its
  main direction (square roots of the structure tensor's eigenvalues in 4 x 4 px windows),
  at full size and at half size.

Plain MSE cannot see a stochastic effect: adding camera noise to sim *raises* it. The texture
term sees noise, texture and blur through their local gradient power, whatever the phase or
orientation. When sim' is stochastic, two draws a, b are rendered and the structure term is
``(La - Lr)(Lb - Lr)``, an unbiased estimate of ``(E[La] - Lr)^2``: the fit then matches the
mean image instead of being penalised for its own randomness.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.breakdown import GAP
from tactile_bench.diagnose.candidates import CANDIDATES, Candidate, Searched, get_candidate
from tactile_bench.diagnose.scene import PairScene
from tactile_bench.diagnose.simulate import bake_fixed, render
from tactile_bench.effects.base import ParamValue
from tactile_bench.effects.kernels import gaussian_blur
from tactile_bench.sensor.timing import timed_span

GAP_METRIC = (
    "structure + texture, grey level^2 (0..255): MSE of the images low-passed to ~1 px "
    "(2x2 area average, then Gaussian sigma 0.5 at half size) + squared difference of the "
    "local gradient strength along and across its main direction (sqrt of the eigenvalues "
    "of the structure tensor in 4 x 4 px windows, at full and at half size); stochastic "
    "sims: two draws, structure unbiased for their mean image, texture averaged"
)
SWEEP_LEVELS = (0.02, 0.25, 0.5, 0.75, 0.98)  # unit-range values of a coordinate sweep
DIFF_SWEEP_LEVELS = (0.1, 0.5, 0.9)  # coarser for parameters Adam refines afterwards
MAX_WHOLE_VALUES = 100  # integer parameters with at most this many values: tried one by one
MAX_WHOLE_POINTS = 400  # combinations of whole values tried jointly (else one at a time)
MAX_GRID_PARAMS = 2  # up to this many gradient-free parameters: a full grid, not a sweep
# integer values (a codec's quality at both frame sizes: 200 points) are screened on this
# many pairs, and the best WHOLE_SHORTLIST of them scored on the Adam pairs
WHOLE_PAIRS = 16
WHOLE_SHORTLIST = 5
#: a point of unit coordinates -> its mean gap
Loss = Callable[[Mapping[str, ParamValue]], float]


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    s = torch.tensor(float(sigma))
    return gaussian_blur(x, s, s)


def _oriented_rms(x: torch.Tensor, window: int) -> torch.Tensor:
    """(2, N, 3, h, w): RMS gradient along and across the main direction of each window.

    The eigenvalues of the structure tensor do not depend on the direction, so a smear in
    a random direction per contact, noise or a blur compare like for like whatever their
    phase or orientation; a smear lowers one, a blur both, noise raises both.
    """
    xp = F.pad(x, (0, 1, 0, 1), mode="replicate")
    gx, gy = xp[..., :-1, 1:] - xp[..., :-1, :-1], xp[..., 1:, :-1] - xp[..., :-1, :-1]
    jxx, jyy = F.avg_pool2d(gx * gx, window), F.avg_pool2d(gy * gy, window)
    jxy = F.avg_pool2d(gx * gy, window)
    half_trace = (jxx + jyy) / 2
    radius = torch.sqrt(((jxx - jyy) / 2).square() + jxy.square() + 1e-6)
    return torch.stack([half_trace + radius, (half_trace - radius).clamp(min=0.0)]).add(1.0).sqrt()


def gap_features(x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """(low-passed image at half size, oriented gradient RMS at two scales) of (N, 3, S, S).

    All but the full-size gradients run at half size: the metric costs a few ms per hundred
    images, which is what lets every candidate be fitted in seconds.
    """
    low = _blur(F.avg_pool2d(x, 2), 0.5)
    return low, [_oriented_rms(x, 4), _oriented_rms(low, 2)]


@dataclass
class Target:
    """The real images of some pairs with their features, computed once."""

    real: torch.Tensor
    low: torch.Tensor
    rms: list[torch.Tensor]

    @classmethod
    def of(cls, real: torch.Tensor) -> Target:
        low, rms = gap_features(real.float())
        return cls(real, low, rms)

    def subset(self, idx: torch.Tensor | slice) -> Target:
        return Target(self.real[idx], self.low[idx], [r[:, idx] for r in self.rms])

    def __len__(self) -> int:
        return len(self.real)


def pair_gap(draws: list[torch.Tensor], target: Target) -> torch.Tensor:
    """Gap (N,) of each pair: one draw for a deterministic sim', two for a stochastic one."""
    with timed_span(GAP):
        feats = [gap_features(d) for d in draws]
        if len(draws) == 1:
            structure = (feats[0][0] - target.low).square().mean((1, 2, 3))
        else:
            structure = ((feats[0][0] - target.low) * (feats[1][0] - target.low)).mean((1, 2, 3))
        texture = torch.zeros_like(structure)
        for k, rms_real in enumerate(target.rms):
            rms = sum(f[1][k] for f in feats) / len(feats)
            texture = texture + (rms - rms_real).square().sum(0).mean((1, 2, 3))
        return structure + texture


def rounding_gap(target: Target, seed: int = 0) -> float:
    """The gap 8-bit rounding alone makes: the real images against themselves plus uniform
    noise of one grey level's width (what storing a frame in 8 bits can change). Fits that
    differ by less explain the same thing as far as 8-bit frames can show."""
    gen = torch.Generator().manual_seed(seed)
    noise = (torch.rand(target.real.shape, generator=gen) - 0.5).to(target.real.device)
    return float(pair_gap([target.real.float() + noise], target).mean())


def _random(effects: Mapping[str, Mapping[str, ParamValue]]) -> bool:
    """True when an effect draws randomness or has a per-pair latent (cannot be baked)."""
    return any(CANDIDATES[n].stochastic or CANDIDATES[n].latent_grid for n in effects)


def is_stochastic(effects: Mapping[str, Mapping[str, ParamValue]]) -> bool:
    """True when the gap of ``effects`` needs two draws (a latent is searched, not drawn)."""
    return any(CANDIDATES[n].stochastic and not CANDIDATES[n].latent_grid for n in effects)


#: a change made to every rendered draw before it is scored: (images, scene, draw) -> images
PostDraw = Callable[[torch.Tensor, PairScene, int], torch.Tensor]


def evaluate(
    scene: PairScene,
    target: Target,
    effects: Mapping[str, Mapping[str, ParamValue]],
    seed: int,
    post: PostDraw | None = None,
) -> torch.Tensor:
    """Per-pair gap (N,) of ``effects`` on ``scene``: two seeded draws when stochastic, and
    for an effect with a per-pair latent the best value of its grid, pair by pair."""
    for name in effects:
        grid = CANDIDATES[name].latent_grid
        if grid and name not in scene.latent:
            gaps = [evaluate(scene.with_latent(name, v), target, effects, seed, post) for v in grid]
            return torch.stack(gaps).min(0).values
    draws = 2 if is_stochastic(effects) else 1
    images = [
        render(scene, effects, torch.Generator().manual_seed(seed + 7919 * k)) for k in range(draws)
    ]
    if post is not None:
        images = [post(image, scene, k) for k, image in enumerate(images)]
    return pair_gap(images, target)


def model_gap(
    scene: PairScene,
    target: Target,
    effects: Mapping[str, Mapping[str, ParamValue]],
    seed: int = 0,
    chunk: int = 256,
    post: PostDraw | None = None,
) -> torch.Tensor:
    """Per-pair gap (N,) of the candidate simulator with ``effects`` against ``target``
    (``post``: applied to each rendered draw before scoring)."""
    out = []
    with torch.no_grad():
        for i in range(0, len(scene), chunk):
            part = slice(i, i + chunk)  # views of the pairs, wherever they live
            out.append(evaluate(scene.subset(part), target.subset(part), effects, seed + i, post))
    return torch.cat(out) if out else scene.depth.new_zeros(0)


@dataclass
class FitBudget:
    """How much of the fit split a fit uses, and how long it searches."""

    sweep_pairs: int = 32
    adam_pairs: int = 64
    adam_steps: int = 25
    lr: float = 0.06


class _Objective:
    """The mean gap of one candidate at a point (unit coordinates) on a fixed subset of the
    fit pairs, the ``prior`` effects in place. The sweeps revisit points (each starts from
    its best so far) and the gap is deterministic, so a point of floats is computed once."""

    def __init__(
        self,
        cand: Candidate,
        scene: PairScene,
        target: Target,
        prior: Mapping[str, Mapping[str, float]],
        seed: int,
    ) -> None:
        self.cand, self.scene, self.target, self.prior, self.seed = (
            cand,
            scene,
            target,
            prior,
            seed,
        )
        self._seen: dict[tuple[float, ...], torch.Tensor] = {}

    def __call__(self, u: Mapping[str, ParamValue]) -> torch.Tensor:
        searched = self.cand.searched
        point = None
        if not any(isinstance(u[s.name], torch.Tensor) for s in searched):
            point = tuple(float(u[s.name]) for s in searched)
            if point in self._seen:
                return self._seen[point]
        params = {s.name: s.from_unit(u[s.name]) for s in searched}
        effects = {**self.prior, self.cand.name: params}
        value = evaluate(self.scene, self.target, effects, self.seed).mean()
        if point is not None:
            self._seen[point] = value
        return value

    def number(self, u: Mapping[str, ParamValue]) -> float:
        return float(self(u))


def fit_candidate(
    name: str,
    scene: PairScene,
    target: Target,
    prior: Mapping[str, Mapping[str, float]] | None = None,
    seed: int = 0,
    budget: FitBudget | None = None,
) -> dict[str, float]:
    """Parameters of candidate ``name`` that minimise the gap on (a subsample of) the fit
    pairs, with ``prior`` effects already in place (held fixed).

    Whole-valued parameters tried value by value -> the other gradient-free ones on a grid
    or a coordinate sweep -> a coarse sweep of the differentiable ones (to leave flat or
    local minima) -> Adam on those in unit coordinates, projected onto the box -> a pattern
    search of the gradient-free ones, and Adam again if that moved anything. Every search
    starts on the neutral side, never at a default.
    """
    cand = get_candidate(name)
    budget = budget or FitBudget()
    scene, prior = _bake_earlier(cand, scene, dict(prior or {}))
    order = torch.randperm(len(scene), generator=torch.Generator().manual_seed(seed))

    def on(n_pairs: int) -> _Objective:
        idx = order[:n_pairs]
        return _Objective(cand, scene.subset(idx), target.subset(idx), prior, seed)

    sweep, adam = on(budget.sweep_pairs), on(budget.adam_pairs)
    u: dict[str, ParamValue] = {s.name: s.to_unit(s.start) for s in cand.searched}
    diff = [s.name for s in cand.searched if s.differentiable]
    whole = [s for s in cand.searched if s.integer and s.high - s.low <= MAX_WHOLE_VALUES]
    other = [s.name for s in cand.searched if not s.differentiable and s not in whole]
    with torch.no_grad():
        _whole_values(u, whole, on(min(WHOLE_PAIRS, budget.sweep_pairs)).number, adam.number)
        _search_gradient_free(u, other, sweep.number)
        _sweep(u, diff, DIFF_SWEEP_LEVELS, sweep.number)
    _adam(u, diff, adam, budget)
    _refine(u, other, diff, sweep if len(other) > 2 else adam, adam, budget)
    return {s.name: s.report(float(u[s.name])) for s in cand.searched}


def _search_gradient_free(u: dict[str, ParamValue], names: list[str], loss_fn: Loss) -> None:
    """Few gradient-free parameters: a full grid (coupled ones, such as a gel's spread and
    the core it holds, stall a sweep one coordinate at a time); many: a sweep."""
    if len(names) <= MAX_GRID_PARAMS:
        fit_on_grid(u, names, loss_fn)
    else:
        _sweep(u, names, SWEEP_LEVELS, loss_fn)


def _bake_earlier(
    cand: Candidate, scene: PairScene, prior: dict[str, Mapping[str, float]]
) -> tuple[PairScene, dict[str, Mapping[str, float]]]:
    """``scene`` with the fixed pose and geometry effects of ``prior`` that act before
    ``cand`` applied once, and the rest of ``prior``: not applied at every step (a codec's
    quality search renders hundreds of times)."""
    earlier = {"pose"} if cand.acts_on == "geometry" else {"pose", "geometry"}
    baked = {n: p for n, p in prior.items() if CANDIDATES[n].acts_on in earlier}
    if baked and cand.acts_on != "pose" and not _random(baked):
        return bake_fixed(scene, baked), {n: p for n, p in prior.items() if n not in baked}
    return scene, prior


def _sweep(
    u: dict[str, ParamValue],
    names: list[str],
    levels: tuple[float, ...],
    loss_fn: Loss,
) -> bool:
    """Coordinate sweep: each of ``names`` in turn moved to its best of ``levels``."""
    best, moved = loss_fn(u), False
    for n in names:
        for level in levels:
            value = loss_fn({**u, n: level})
            if value < best - 1e-9:
                best, u[n], moved = value, level, True
    return moved


def _whole_values(
    u: dict[str, ParamValue],
    whole: list[Searched],
    quick_loss: Loss,
    loss_on_more: Loss,
) -> None:
    """Integer parameters (``whole``, searched specs) set to their best combination: every
    combination scored by ``quick_loss`` (``WHOLE_PAIRS`` pairs), the best
    ``WHOLE_SHORTLIST`` by ``loss_on_more``. Jointly when there are at most
    ``MAX_WHOLE_POINTS`` (a codec's quality that fits one frame size misfits the other),
    else one parameter at a time."""
    grids = [[s.to_unit(v) for v in range(math.ceil(s.low), math.floor(s.high) + 1)] for s in whole]
    joint = math.prod(len(g) for g in grids) <= MAX_WHOLE_POINTS
    for names, values in (
        [([s.name for s in whole], grids)]
        if joint
        else [([s.name], [g]) for s, g in zip(whole, grids, strict=True)]
    ):
        points = [dict(zip(names, lv, strict=True)) for lv in itertools.product(*values)]
        scores = sorted(
            ((quick_loss({**u, **pt}), i) for i, pt in enumerate(points)), key=lambda t: t[0]
        )
        best = min((loss_on_more({**u, **points[i]}), i) for _, i in scores[:WHOLE_SHORTLIST])
        u.update(points[best[1]])


def fit_on_grid(u: dict[str, ParamValue], names: list[str], loss_fn: Loss) -> None:
    """``names`` set to their best point on the full grid of ``SWEEP_LEVELS`` (coupled
    parameters, such as a gel's spread and the core it holds, have no good value of one at
    the other's start: a sweep one coordinate at a time stalls there)."""
    best = (loss_fn(u), {n: u[n] for n in names})
    # each parameter's start is a level too: the grid holds every point a sweep from the
    # start could end on, so it never does worse than the sweep it replaces
    axes = [sorted({*SWEEP_LEVELS, float(u[n])}) for n in names]
    for levels in itertools.product(*axes):
        trial = dict(zip(names, levels, strict=True))
        value = loss_fn({**u, **trial})
        if value < best[0] - 1e-9:
            best = (value, trial)
    u.update(best[1])


def _refine(
    u: dict[str, ParamValue],
    names: list[str],
    diff: list[str],
    loss_fn: _Objective,
    adam_loss: _Objective,
    budget: FitBudget,
    rounds: int = 2,
) -> None:
    """Pattern search of ``names`` around the sweep's best (+-half the level step, halved
    each round); if it moved anything, Adam again on ``diff`` for half the steps."""
    if not names:
        return
    moved = False
    with torch.no_grad():
        best = loss_fn.number(u)
        step = 0.5 * (SWEEP_LEVELS[1] - SWEEP_LEVELS[0])
        for _ in range(rounds):
            for n in names:
                for sign in (-1.0, 1.0):
                    level = min(max(float(u[n]) + sign * step, 0.0), 1.0)
                    value = loss_fn.number({**u, n: level})
                    if value < best - 1e-9:
                        best, u[n], moved = value, level, True
            step /= 2
    if moved and diff:
        _adam(u, diff, adam_loss, budget, steps=budget.adam_steps // 2)


def _adam(
    u: dict[str, ParamValue],
    names: list[str],
    loss_fn: Callable[[Mapping[str, ParamValue]], torch.Tensor],
    budget: FitBudget,
    steps: int | None = None,
) -> None:
    """Projected Adam on ``u[names]`` (unit coordinates, kept in [0, 1]); keeps the best."""
    if not names:
        return
    z = torch.tensor([float(u[n]) for n in names], requires_grad=True)
    opt = torch.optim.Adam([z], lr=budget.lr)
    best_value, best_z = math.inf, z.detach().clone()
    for _ in range(budget.adam_steps if steps is None else steps):
        value = loss_fn({**u, **{n: z[i] for i, n in enumerate(names)}})
        if float(value.detach()) < best_value:
            best_value, best_z = float(value.detach()), z.detach().clone()
        if not value.requires_grad:  # e.g. a blur too narrow to act: no gradient here
            break
        opt.zero_grad()
        value.backward()
        opt.step()
        with torch.no_grad():
            z.clamp_(0.0, 1.0)
    with torch.no_grad():
        final = float(loss_fn({**u, **{n: z[i] for i, n in enumerate(names)}}))
    if final < best_value:
        best_z = z.detach().clone()
    for i, n in enumerate(names):
        u[n] = float(best_z[i])


def fit_jointly(
    effects: Mapping[str, Mapping[str, float]],
    scene: PairScene,
    target: Target,
    seed: int = 0,
    budget: FitBudget | None = None,
) -> dict[str, dict[str, float]]:
    """Refit the differentiable parameters of several effects together (Adam, from their
    current values); the others stay. Effects that interact (a gain and a tone curve) then
    share out the gap instead of each keeping what it took when it was selected."""
    budget = budget or FitBudget()
    searched = {n: {s.name: s for s in get_candidate(n).searched} for n in effects}
    keys = [(n, k) for n in effects for k, s in searched[n].items() if s.differentiable]
    u: dict[str, ParamValue] = {
        f"{n}/{k}": searched[n][k].to_unit(float(effects[n][k])) for n, k in keys
    }
    idx = torch.randperm(len(scene), generator=torch.Generator().manual_seed(seed))
    sub, tgt = scene.subset(idx[: budget.adam_pairs]), target.subset(idx[: budget.adam_pairs])

    def loss(values: Mapping[str, ParamValue]) -> torch.Tensor:
        params = {n: dict(p) for n, p in effects.items()}
        for n, k in keys:
            params[n][k] = searched[n][k].from_unit(values[f"{n}/{k}"])
        return evaluate(sub, tgt, params, seed).mean()

    _adam(u, list(u), loss, budget)
    out = {n: dict(p) for n, p in effects.items()}
    for n, k in keys:
        out[n][k] = searched[n][k].report(float(u[f"{n}/{k}"]))
    return out
