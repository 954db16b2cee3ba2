"""The candidate simulator's starting point: what paired data hold, never a sensor profile.

A ``PairScene`` is some pairs' sim image split into the sim's own no-contact frame and the
contact's colour change, with their depth, composited onto the **measured** no-contact frame
(the background correction the data give). ``FitReference`` is what the fit split lends every
scene of one diagnosis: the pairs the optical-response lookup is fitted on, the lookups fitted
so far, and the user's sim optics (the built-in ``SimOptics`` or a lookup fitted to their
(depth, sim) pairs, whichever reproduces their sim better). See docs/diagnosis.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.effects import EffectContext
from tactile_bench.effects.kernels import gaussian_blur
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.response_fit import fit_response, predict_delta

GEL = GelSpec()  # the view when paired data name none (gel.json): a DIGIT's 18 x 24 mm
OVERSAMPLE = 2  # geometry effects act at this multiple of the image size
# fit-split pairs the optical-response lookup is fitted on (the first): 22 x 6 coefficients
# a channel, and this many contacts hold far more pixels than that
LOOKUP_PAIRS = 64


@dataclass(frozen=True)
class SimOpticsChoice:
    """The user's sim optics: a fitted lookup (F, 3, 6), or None for the built-in
    ``SimOptics``; each model's MSE on held-in sim images (the floor of geometry fits)."""

    lookup: torch.Tensor | None
    builtin_mse: float
    lookup_mse: float

    def report(self) -> dict[str, object]:
        return {
            "model": "fitted lookup" if self.lookup is not None else "built-in SimOptics",
            "builtin_mse": None if math.isnan(self.builtin_mse) else round(self.builtin_mse, 3),
            "lookup_mse": None if math.isnan(self.lookup_mse) else round(self.lookup_mse, 3),
        }


@dataclass
class FitReference:
    """The fit split's (depth, real - measured frame): what the optical-response lookup is
    fitted on (never the pairs it is scored on); the lookups fitted so far, by the geometry
    they were fitted under; and the user's sim optics."""

    depth: torch.Tensor
    real_change: torch.Tensor
    sim_optics: SimOpticsChoice
    lookups: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)


def fit_reference(data: DiagnosisPairs, fit_idx: torch.Tensor) -> FitReference:
    """The reference the fit split's first ``LOOKUP_PAIRS`` pairs lend every scene."""
    fit = data.subset(torch.as_tensor(fit_idx, dtype=torch.long)[:LOOKUP_PAIRS])
    fit_bg = (fit.sim_background if fit.sim_background is not None else fit.background).float()
    sim_change = fit.sim.float() - fit_bg[None]
    choice = sim_optics_model(fit.depth.float(), sim_change, fit_bg, tuple(fit.gel_mm))
    real_change = fit.real.float() - fit.background.float()[None]
    return FitReference(fit.depth.float(), real_change, choice)


@dataclass
class PairScene:
    """Some pairs as the candidate simulator starts from them (module docstring)."""

    depth: torch.Tensor  # (N, 1, S, S) mm
    delta: torch.Tensor  # (N, 3, S, S) sim - the sim's no-contact frame
    background: torch.Tensor  # (1, 3, S, S) the frame candidates composite onto
    measured: torch.Tensor  # (3, S, S) the real sensor's no-contact frame
    # (1, 3, S, S) the light the sim saw with no contact: its own no-contact frame (the
    # measured one when the sim was composited onto it)
    sim_frame: torch.Tensor
    gel_mm: tuple[float, float] = (GEL.width_mm, GEL.height_mm)  # the view the images cover
    # False when the sim was composited onto the measured frame: ``sim_frame`` is not its own
    sim_frame_given: bool = True
    reference: FitReference | None = None  # shared by every scene of one diagnosis
    latent: dict[str, torch.Tensor] = field(default_factory=dict)  # per-pair hidden values
    baked: dict[str, dict[str, float]] = field(default_factory=dict)  # geometry in ``depth``
    lookup: torch.Tensor | None = None  # the response lookup of the current render
    _shading: dict[int, torch.Tensor] = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.depth)

    @property
    def size(self) -> int:
        return int(self.depth.shape[-1])

    @property
    def sim_lookup(self) -> torch.Tensor | None:
        """The user's sim optics as a lookup; None: the built-in ``SimOptics``."""
        return None if self.reference is None else self.reference.sim_optics.lookup

    def sim_change(self, height: torch.Tensor) -> torch.Tensor:
        """The sim's noise-free colour change of ``height`` by the user's sim optics (the
        built-in one over the sim's own frame, as the sim rendered it: it clamps)."""
        if self.sim_lookup is not None:
            return predict_delta(height, self.sim_lookup, self.gel_mm)
        return sim_shading(height, self.sim_frame, self.gel_mm)

    def context(self, stochastic: bool = True) -> EffectContext:
        """The effects' context for these pairs: their gel view."""
        return EffectContext(self.gel_mm[0], self.gel_mm[1], stochastic)

    def subset(self, idx: torch.Tensor | slice) -> PairScene:
        shading = {k: v[idx] for k, v in self._shading.items()}
        latent = {k: v[idx] for k, v in self.latent.items()}
        return replace(
            self, depth=self.depth[idx], delta=self.delta[idx], _shading=shading, latent=latent
        )

    def with_latent(self, name: str, value: float) -> PairScene:
        """The same pairs with ``name``'s hidden per-pair value set to ``value`` for all."""
        latent = {**self.latent, name: self.depth.new_full((len(self),), float(value))}
        return replace(self, latent=latent)

    def with_contact(self, depth: torch.Tensor, delta: torch.Tensor) -> PairScene:
        """The same pairs with a new depth and colour change (cached shading dropped)."""
        return replace(self, depth=depth, delta=delta, _shading={})

    def flat(self) -> PairScene:
        """One pair with no contact: the scene of the no-contact frame."""
        depth, delta = (
            self.depth.new_zeros(1, 1, self.size, self.size),
            self.depth.new_zeros(1, 3, self.size, self.size),
        )
        return replace(self, depth=depth, delta=delta, _shading={}, latent={})

    def depth_at(self, factor: int) -> torch.Tensor:
        """The depth resampled to ``factor`` x the image size (bilinear)."""
        if factor == 1:
            return self.depth
        return F.interpolate(self.depth, scale_factor=factor, mode="bilinear")

    def shading(self, factor: int = 1) -> torch.Tensor:
        """The sim optics' colour change of the unaltered depth, after the same round trip
        through ``factor`` x the size as the geometry effects take: cached."""
        if factor not in self._shading:
            height = F.avg_pool2d(self.depth_at(factor), factor) if factor > 1 else self.depth
            self._shading[factor] = self.sim_change(height)
        return self._shading[factor]

    def precompute(self) -> PairScene:
        """Cache the shading at every factor the candidates use (before taking subsets)."""
        for factor in {1, OVERSAMPLE}:
            self.shading(factor)
        return self


def make_scene(
    data: DiagnosisPairs,
    idx: torch.Tensor | None = None,
    reference: FitReference | None = None,
    onto_measured: bool = True,
) -> PairScene:
    """The scene of the pairs at ``idx`` (all by default).

    The sim's colour change is composited onto the **measured** no-contact frame;
    ``onto_measured=False`` keeps the sim's own frame, so the scene with no effect is the
    sim image itself (the gap before correction). ``reference``: the fit split's, which the
    optical-response lookup and the user's sim optics come from; without it that candidate
    cannot render and geometry re-renders with the built-in optics.
    """
    if idx is not None:
        data = data.subset(torch.as_tensor(idx, dtype=torch.long))
    sim_bg = data.sim_background if data.sim_background is not None else data.background
    sim_bg = sim_bg.float()[None]
    measured = data.background.float()
    return PairScene(
        depth=data.depth.float(),
        delta=data.sim.float() - sim_bg,
        background=measured[None] if onto_measured else sim_bg,
        measured=measured,
        sim_frame=sim_bg,
        gel_mm=tuple(data.gel_mm),
        sim_frame_given=data.sim_background is not None,
        reference=reference,
    )


def sim_optics_model(
    depth: torch.Tensor,
    delta: torch.Tensor,
    background: torch.Tensor,
    gel_mm: tuple[float, float],
) -> SimOpticsChoice:
    """The user's sim optics from their (depth, sim colour change) pairs: a fitted lookup,
    or the built-in ``SimOptics`` when that reproduces their sim better. Chosen on the
    second half of the pairs with the lookup fitted on the first."""
    half = len(depth) // 2
    if half < 1 or not bool((depth > 0).any()):
        return SimOpticsChoice(None, math.nan, math.nan)
    held_depth, held_delta = depth[half:], delta[half:]
    shaded = sim_shading(held_depth, background, gel_mm)  # over the sim's frame: it clamps
    builtin = float((shaded - held_delta).square().mean())
    try:
        table = fit_response(depth[:half], delta[:half], gel_mm)
        table = torch.as_tensor(table, device=depth.device).float()
    except ValueError:  # no contact in the first half
        return SimOpticsChoice(None, builtin, math.nan)
    with torch.no_grad():
        fitted = float((predict_delta(held_depth, table, gel_mm) - held_delta).square().mean())
    if fitted >= builtin:
        return SimOpticsChoice(None, builtin, fitted)
    return SimOpticsChoice(
        torch.as_tensor(fit_response(depth, delta, gel_mm), device=depth.device).float(),
        builtin,
        fitted,
    )


def sim_shading(
    height: torch.Tensor,
    background: torch.Tensor,
    gel_mm: tuple[float, float] = (GEL.width_mm, GEL.height_mm),
) -> torch.Tensor:
    """SimOptics' noise-free colour change of ``height`` over ``background`` (as the surrogate)."""
    gel = GelSpec(gel_mm[0], gel_mm[1], height.shape[-1], 1)
    bg = background.reshape(3, *background.shape[-2:])
    return SimOptics().render(height, bg, None, gel) - bg


def fine_scale(x: torch.Tensor, sigma_px: float = 3.0) -> torch.Tensor:
    """``x / blur(x)``: what a smooth field lacks at scales below ``sigma_px`` (dust, scratches)."""
    s = torch.tensor(sigma_px)
    return x / gaussian_blur(x, s, s).clamp(min=1.0)
