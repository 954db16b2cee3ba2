"""Candidate effects: how each catalogue effect is added to paired sim data, from the data only.

The candidate simulator starts from what paired data hold, never from a sensor profile:

- the **base scene** of a pair is its sim image split into background and colour change:
  ``delta = sim - data.sim_background`` (``data.background`` when the sim was composited
  onto the measured frame), height = the pair's depth, unit gain, composited onto the
  **measured** no-contact frame: the background correction, given by the data and reported
  as the ranking's first line (``which``);
- the measured frame already went through the real sensor, so a candidate never applies
  an effect to it a second time: the sim's own frame is taken through the candidate's
  optics and linear camera effects with and without the contact, and the **difference**
  (the contact's change as that sensor sees it) is added to the measured frame. The
  camera's nonlinear steps act where the real ones did: a tone curve on the light the real
  sensor saw (the measured frame undone through the curve, ``ToneCurve.undo``) plus that
  change; a codec on the sim's own uncompressed frame plus the change, its coded
  difference added to the measured frame (coding the measured frame again would compress
  it twice); per-frame noise (``whole_frame``) on the whole composite;
- **geometry** effects change the height (sub-pixel texture at 2x the image size,
  area-averaged back as a camera integrates), and their colour change is re-rendered
  *linearly*: ``delta + S(h') - S(h)``, with ``S`` **the user's sim optics**: the built-in
  TACTO-like ``SimOptics`` (exact for the built-in simulator) or a lookup of colour change
  against surface slope and position fitted to the fit split's (depth, sim) pairs
  (``sensor.response_fit``), whichever reproduces held-in sim images better
  (``sim_optics_model``; its error is reported: below it no effect can be told apart);
- **optics** effects act on that scene, **camera** effects on its composite, as in
  ``SurrogateDigit``;
- ``optical_response`` is a **lookup fitted from the pairs** (colour change against the
  surface slope and the pixel position, as Taxim calibrates a sensor from ball presses;
  ``sensor.response_fit``), by least squares on the *fit split's* real frames minus the
  measured no-contact frame, under whatever gel geometry the candidate set applies (refitted,
  cached, when that geometry changes). It stands for any sensor's own optics, not one
  DIGIT's table; ``blend`` moves the sim's colour change towards it.

Every parameter not searched is held at its **neutral** value: ``Effect.apply`` fills
missing parameters with *defaults*, the very values the default surrogate profile uses, so
they are never left to it. Nothing here reads ``Param.default``.

Left out or modelled differently, and why:

- ``pose_error`` is fitted as a constant **misregistration** of the depth against the real
  frames: the depth and the sim's colour change are warped together (a shift in mm and a
  rotation about the view's centre, bilinear), so no optics model is needed. The random
  part per contact (jitter) is not searched.
- ``press_error`` is fitted as a **depth scale and offset** of each contact's peak
  penetration: the contact's depth moves by ``(scale - 1) * peak + offset`` where it is
  positive and is re-rendered with the user's sim optics. A deeper press would also widen
  the contact where the depth is 0 (the object's height there is unknown): not modelled;
  nor is the per-contact jitter.
- ``gel_wear``: dust and scratches sit where the unit's random draw (``unit_seed``) put
  them, which no parameter search can find. They also darken the measured no-contact frame,
  so the candidate reads them from the data: the fine-scale transmission
  ``fine(data.background) / fine(sim background)`` (``fine(x) = x / blur(x)``),
  raised to ``measured_wear`` in [0, 1]; only ``coating_wear`` (the worn centre's lost
  response, centred) is an effect parameter searched.
- ``surface_texture``: the beads follow each contact's yaw, which paired data lack: they
  are laid along image axes (``bead_angle_deg`` held at 0), and only where the depth is
  positive (off the contact the true height below the gel is unknown).
- ``shear_smear``: the slip direction is random per contact, so it is a per-pair latent
  (the gap takes the best of 8 directions pair by pair); the length is the shared parameter.
- ``jpeg``: quality is searched value by value (the codec rounds it, and the gap drops only
  at the exact value), at the sensor's native frame or at the stored size (``stored_size``).
- ``unit_background`` moves and tints the no-contact frame only: the measured frame
  replaces it, so it is the background line, not a candidate.
- Geometry parameters are searched without gradients: their change reaches the image
  through the simulator's optics, a black box.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.paired import PairedData
from tactile_bench.effects import EFFECT_ORDER, EFFECTS, Effect, EffectContext
from tactile_bench.effects.base import ParamValue
from tactile_bench.effects.camera import libjpeg
from tactile_bench.effects.kernels import gaussian_blur
from tactile_bench.effects.optics import new_scene
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.response_fit import fit_response, predict_delta, response_design

GEL = GelSpec()  # the view when paired data name none (gel.json): a DIGIT's 18 x 24 mm
OVERSAMPLE = 2  # geometry effects act at this multiple of the image size
LOOKUP_PAIRS = 64  # fit-split pairs the optical-response lookup is fitted on (the first)
SIM_MODEL_KEY = "__sim_optics__"  # the lookup cache's entry for the user's sim optics
NOT_CANDIDATES: dict[str, str] = {
    # it changes the no-contact frame only, and candidates composite onto the measured one
    "unit_background": "given by the data: the measured no-contact frame replaces the sim's "
    "(the background line of the ranking)",
}
DEFAULT_CANDIDATES: tuple[str, ...] = tuple(n for n in EFFECT_ORDER if n not in NOT_CANDIDATES)


@dataclass(frozen=True)
class Searched:
    """One parameter the fit searches, within [low, high]; ``start`` is a neutral-side guess."""

    name: str
    low: float
    high: float
    start: float
    differentiable: bool
    integer: bool = False  # the effect uses only whole values: searched value by value

    def to_unit(self, value: float) -> float:
        return (value - self.low) / (self.high - self.low)

    def from_unit(self, u: Any) -> Any:
        value = self.low + (self.high - self.low) * u
        # Effect.validate checks ranges in float32: keep the value's float32 inside the box
        low, high = _f32_inside(self.low, 1), _f32_inside(self.high, -1)
        if isinstance(value, torch.Tensor):
            return value.clamp(low, high)
        return min(max(value, low), high)

    def report(self, u: float) -> float:
        """A fitted value for reports and ``apply_effects``: 5 significant digits, in range."""
        value = float(f"{self.from_unit(float(u)):.5g}")
        if self.integer:
            value = float(round(value))
        return min(max(value, _f32_inside(self.low, 1)), _f32_inside(self.high, -1))


def _f32_inside(bound: float, direction: int) -> float:
    """The float32 nearest ``bound`` on its inner side (``direction`` +1: above it)."""
    t = torch.tensor(bound, dtype=torch.float32)
    if (float(t) - bound) * direction < 0:
        t = torch.nextafter(t, torch.tensor(direction * math.inf, dtype=torch.float32))
    return float(t)


@dataclass
class Base:
    """The candidate simulator's starting point for some pairs (see the module docstring)."""

    depth: torch.Tensor  # (N, 1, S, S) mm
    delta: torch.Tensor  # (N, 3, S, S) sim - the sim's no-contact frame
    background: torch.Tensor  # (1, 3, S, S) the frame candidates composite onto
    measured: torch.Tensor  # (3, S, S) the real sensor's no-contact frame
    _shading: dict[int, torch.Tensor] = field(default_factory=dict, repr=False)
    latent: dict[str, torch.Tensor] = field(default_factory=dict)  # per-pair hidden values
    gel_mm: tuple[float, float] = (GEL.width_mm, GEL.height_mm)  # the view the images cover
    # the fit split's (depth, real - measured background): what the response lookup is
    # fitted on; shared by every base of one diagnosis, as is the cache of fitted lookups
    lookup_fit: tuple[torch.Tensor, torch.Tensor] | None = None
    lookup_cache: dict[str, torch.Tensor] = field(default_factory=dict, repr=False)
    baked: dict[str, Any] = field(default_factory=dict)  # geometry already in ``depth``
    lookup: torch.Tensor | None = None  # the lookup for the current render (set by render)
    # (1, 3, S, S) the sim's own no-contact frame (the measured one when the sim was
    # composited onto it): the reference ``gel_wear`` reads dust and scratches against
    sim_background: torch.Tensor | None = None
    # the user's sim optics as a fitted lookup (F, 3, 6), None: the built-in SimOptics
    sim_lookup: torch.Tensor | None = None

    @property
    def sim_frame(self) -> torch.Tensor:
        """(1, 3, S, S) the light the sim saw with no contact: its own no-contact frame."""
        return self.sim_background if self.sim_background is not None else self.background

    def sim_change(self, height: torch.Tensor) -> torch.Tensor:
        """The sim's noise-free colour change of ``height`` by the user's sim optics (the
        built-in one over the sim's own frame, as the sim rendered it: it clamps)."""
        if self.sim_lookup is not None:
            return predict_delta(height, self.sim_lookup, self.gel_mm)
        return sim_shading(height, self.sim_frame, self.gel_mm)

    def context(self, stochastic: bool = True) -> EffectContext:
        """The effects' context for these pairs: their gel view."""
        return EffectContext(self.gel_mm[0], self.gel_mm[1], stochastic)

    def __len__(self) -> int:
        return len(self.depth)

    @property
    def size(self) -> int:
        return int(self.depth.shape[-1])

    def subset(self, idx: torch.Tensor) -> Base:
        shading = {k: v[idx] for k, v in self._shading.items()}
        latent = {k: v[idx] for k, v in self.latent.items()}
        return replace(
            self, depth=self.depth[idx], delta=self.delta[idx], _shading=shading, latent=latent
        )

    def with_latent(self, name: str, value: float) -> Base:
        """The same pairs with ``name``'s hidden per-pair value set to ``value`` for all."""
        latent = {**self.latent, name: torch.full((len(self),), float(value))}
        return replace(self, latent=latent)

    def depth_at(self, factor: int) -> torch.Tensor:
        """The depth resampled to ``factor`` x the image size (bilinear)."""
        if factor == 1:
            return self.depth
        return F.interpolate(self.depth, scale_factor=factor, mode="bilinear")

    def shading(self, factor: int = 1) -> torch.Tensor:
        """SimOptics' noise-free colour change of the unaltered depth, after the same round
        trip through ``factor`` x the size as the geometry effects take: cached."""
        if factor not in self._shading:
            height = F.avg_pool2d(self.depth_at(factor), factor) if factor > 1 else self.depth
            self._shading[factor] = self.sim_change(height)
        return self._shading[factor]

    def precompute(self) -> Base:
        """Cache the shading at every factor the candidates use (before taking subsets)."""
        for factor in {1, OVERSAMPLE}:
            self.shading(factor)
        return self


def make_base(
    data: PairedData,
    idx: torch.Tensor | None = None,
    lookup_from: torch.Tensor | None = None,
    lookup_cache: dict[str, torch.Tensor] | None = None,
    onto_measured: bool = True,
) -> Base:
    """The base scene of the pairs at ``idx`` (all by default).

    The sim's colour change is composited onto the **measured** no-contact frame (the
    background correction, given by the data); ``onto_measured=False`` keeps the sim's own
    frame, so the base with no effect is the sim image itself (the gap before correction).
    ``lookup_from``: the fit split, whose real frames the ``optical_response`` lookup is
    fitted on (never the pairs it is scored on); without it that candidate cannot render.
    Bases of one diagnosis share ``lookup_cache`` so each lookup is fitted once.
    """
    lookup_fit = None
    cache = lookup_cache if lookup_cache is not None else {}
    sim_lookup = None
    if lookup_from is not None:
        # 22 x 6 coefficients a channel: LOOKUP_PAIRS contacts hold far more pixels than that
        fit = data.subset(torch.as_tensor(lookup_from, dtype=torch.long)[:LOOKUP_PAIRS])
        lookup_fit = (fit.depth.float(), fit.real.float() - fit.background.float()[None])
        if SIM_MODEL_KEY not in cache:
            fit_bg = fit.sim_background if fit.sim_background is not None else fit.background
            delta = fit.sim.float() - fit_bg.float()[None]
            cache[SIM_MODEL_KEY], cache[SIM_MODEL_KEY + "report"] = sim_optics_model(
                fit.depth.float(), delta, fit_bg.float(), tuple(fit.gel_mm)
            )
        sim_lookup = cache[SIM_MODEL_KEY] if cache[SIM_MODEL_KEY].numel() else None
    if idx is not None:
        data = data.subset(idx)
    sim_bg = data.sim_background if data.sim_background is not None else data.background
    sim_bg = sim_bg.float()[None]
    measured = data.background.float()
    return Base(
        data.depth.float(),
        data.sim.float() - sim_bg,
        measured[None] if onto_measured else sim_bg,
        measured,
        gel_mm=tuple(data.gel_mm),
        lookup_fit=lookup_fit,
        lookup_cache=cache,
        sim_background=sim_bg,
        sim_lookup=sim_lookup,
    )


def sim_optics_model(
    depth: torch.Tensor,
    delta: torch.Tensor,
    background: torch.Tensor,
    gel_mm: tuple[float, float],
) -> tuple[torch.Tensor, torch.Tensor]:
    """The user's sim optics from their (depth, sim colour change) pairs: a fitted lookup,
    or the built-in ``SimOptics`` (an empty table) when that reproduces their sim better.

    Chosen on the second half of the pairs with the lookup fitted on the first; returns
    (table, [built-in MSE, lookup MSE] on that half: the floor of any geometry effect)."""
    half = len(depth) // 2
    if half < 1 or not bool((depth > 0).any()):
        return torch.zeros(0), torch.tensor([math.nan, math.nan])
    held_depth, held_delta = depth[half:], delta[half:]
    shaded = sim_shading(held_depth, background, gel_mm)  # over the sim's frame: it clamps
    builtin = float((shaded - held_delta).square().mean())
    try:
        table = torch.as_tensor(fit_response(depth[:half], delta[:half], gel_mm)).float()
    except ValueError:  # no contact in the first half
        return torch.zeros(0), torch.tensor([builtin, math.nan])
    with torch.no_grad():
        fitted = float((predict_delta(held_depth, table, gel_mm) - held_delta).square().mean())
    errors = torch.tensor([builtin, fitted])
    if fitted >= builtin:
        return torch.zeros(0), errors
    return torch.as_tensor(fit_response(depth, delta, gel_mm)).float(), errors


def sim_optics_report(base: Base) -> dict[str, Any]:
    """Which sim optics ``base``'s geometry re-renders with, and both models' held-in MSE."""
    if SIM_MODEL_KEY not in base.lookup_cache:
        return {}
    builtin, fitted = base.lookup_cache[SIM_MODEL_KEY + "report"].tolist()
    return {
        "model": "fitted lookup" if base.sim_lookup is not None else "built-in SimOptics",
        "builtin_mse": None if math.isnan(builtin) else round(builtin, 3),
        "lookup_mse": None if math.isnan(fitted) else round(fitted, 3),
    }


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


class Candidate:
    """How one catalogue effect is searched and applied to a ``Base``.

    ``searched``: the parameters a fit varies (others held at neutral). ``apply`` takes the
    data of the part it acts on like ``Effect.apply`` plus the ``Base`` (for data-derived
    parts).
    """

    def __init__(
        self,
        effect: Effect,
        skip: tuple[str, ...] = (),
        note: str = "",
        fixed: Mapping[str, float] | None = None,
        integer: tuple[str, ...] = (),
    ) -> None:
        self.effect = effect
        # a camera effect drawn anew for every frame (noise): a measured no-contact frame
        # holds no draw of this frame's, so it is applied to the composite as a whole
        self.whole_frame = effect.stochastic
        self.fixed = dict(fixed or {})  # held values of skipped parameters (else neutral)
        skip = tuple(skip) + tuple(self.fixed)
        self.name = effect.name
        self.acts_on = effect.acts_on
        self.stochastic = effect.stochastic
        self.note = note
        # geometry changes reach the image through the simulator's optics, a black box (a
        # user's own simulator, or SimOptics' in-place kernels): searched without gradients
        self.searched = tuple(
            Searched(
                p.name,
                p.low,
                p.high,
                _start(p.low, p.high, p.neutral),
                diff,
                p.integer or p.name in integer,
            )
            for p in effect.params
            if p.name not in skip
            for diff in [p.name in effect.differentiable and effect.acts_on != "geometry"]
        )

    latent_grid: tuple[float, ...] = ()  # values of a per-pair hidden variable, tried per pair
    oversample = 1  # geometry at this multiple of the image size (sub-pixel detail: > 1)
    # a pointwise, invertible camera curve: it acts at the real light's level, which
    # ``undo`` reads from the measured no-contact frame (module docstring)
    tone_curve = False
    # a codec: it acts around an uncompressed frame, never on one it already compressed
    codec = False

    def fitted_numbers(self, base: Base) -> int:
        """How many numbers a fit of this candidate sets from the data (its searched
        parameters, plus any table or per-pair value it fits): its freedom to absorb a gap."""
        return len(self.searched) + len(base) * bool(self.latent_grid)

    def full_params(self, params: Mapping[str, ParamValue]) -> dict[str, ParamValue]:
        """Every effect parameter: the given ones, neutral for the rest (never the defaults)."""
        out: dict[str, ParamValue] = {**self.effect.neutral_params(), **self.fixed}
        out.update({k: v for k, v in params.items() if k in out})
        return out

    def check(self, params: Mapping[str, ParamValue]) -> None:
        known = {p.name for p in self.effect.params} | {s.name for s in self.searched}
        bad = sorted(set(params) - known)
        if bad:
            raise TactileBenchError(
                f"candidate {self.name!r}: unknown parameter {bad[0]!r}; known: {sorted(known)}"
            )

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        return self.effect.apply(x, self.full_params(params), generator, ctx)


def _start(low: float, high: float, neutral: float) -> float:
    """A starting value on the neutral side: neutral nudged 10% of the range inside the box
    (gradients vanish at a bound such as a zero blur or noise)."""
    span = high - low
    return min(max(neutral, low + 0.1 * span), high - 0.1 * span)


class MeasuredWear(Candidate):
    """gel_wear: the coating's worn centre as a parameter, dust and scratches from the data."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=tuple(p.name for p in effect.params if p.name != "coating_wear"),
            note="dust and scratches read from the measured no-contact frame (measured_wear)",
        )
        self.searched = self.searched + (Searched("measured_wear", 0.0, 1.0, 0.1, True),)

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        x = self.effect.apply(x, self.full_params(params), generator, ctx)
        strength = params.get("measured_wear", 0.0)
        if isinstance(strength, float | int) and strength == 0:
            return x
        ratio = fine_scale(base.measured[None]) / fine_scale(base.sim_frame)
        transmission = ratio.mean(1, keepdim=True).clamp(1e-3, 1.0)
        return x.replace(gain=x.gain * transmission ** torch.as_tensor(strength))


class ContactTexture(Candidate):
    """surface_texture on the contact only: paired depth is 0 wherever the object does not
    touch (its true height there, below the gel, is unknown), and texture must not lift it.
    Beads and terraces are finer than a pixel: rendered at ``OVERSAMPLE`` x, area-averaged."""

    oversample = OVERSAMPLE

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        y = self.effect.apply(x, self.full_params(params), generator, ctx)
        return torch.where(x > 0, y, x)


class LatentSmear(Candidate):
    """shear_smear: the slip direction of each contact is random and unknown, so it is a
    per-pair latent. Without one (``apply_effects``) the effect draws it, as the sensor does;
    the gap measure instead takes, pair by pair, the best of ``latent_grid`` directions, so
    only the smear length is a shared parameter (fitted on the fit split)."""

    latent_grid = tuple(float(a) for a in range(0, 360, 45))  # deg, image axes

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        if self.name not in base.latent:
            return self.effect.apply(x, self.full_params(params), generator, ctx)
        length = float(self.full_params(params)["smear_mm"])
        out = torch.empty_like(x)
        angles = base.latent[self.name]
        for angle in torch.unique(angles).tolist():
            idx = (angles == angle).nonzero().squeeze(1)
            out[idx] = _smear(x[idx], length, math.radians(angle), ctx, self.effect.steps)
        return out


def _smear(
    x: torch.Tensor, length: float, theta: float, ctx: EffectContext, steps: int
) -> torch.Tensor:
    """ShearSmear for one direction: the mean of ``steps`` bilinear samples of ``x`` along the
    path p + t (cos, sin), t in [0, length] mm, clamped at the border; one small conv."""
    dx, dy = ctx.mm_per_px(x)
    ts = torch.linspace(0.0, length, steps, dtype=torch.float64)
    ox, oy = ts * math.cos(theta) / dx, ts * math.sin(theta) / dy
    fx, fy = torch.floor(ox), torch.floor(oy)
    lo_x, lo_y = int(fx.min()), int(fy.min())
    kernel = torch.zeros(int(fy.max()) - lo_y + 2, int(fx.max()) - lo_x + 2, dtype=torch.float64)
    for k in range(steps):
        i, j = int(fy[k]) - lo_y, int(fx[k]) - lo_x
        wy, wx = float(oy[k] - fy[k]), float(ox[k] - fx[k])
        kernel[i : i + 2, j : j + 2] += torch.tensor(
            [[(1 - wy) * (1 - wx), (1 - wy) * wx], [wy * (1 - wx), wy * wx]], dtype=torch.float64
        )
    kh, kw = kernel.shape
    pad = (max(0, -lo_x), max(0, lo_x + kw - 1), max(0, -lo_y), max(0, lo_y + kh - 1))
    n, c, h, w = x.shape
    xp = F.pad(x.reshape(n * c, 1, h, w), pad, mode="replicate")
    y = F.conv2d(xp, (kernel / steps).to(x)[None, None])
    i0, j0 = lo_y + pad[2], lo_x + pad[0]
    return y[..., i0 : i0 + h, j0 : j0 + w].reshape(n, c, h, w)


class FittedResponse(Candidate):
    """optical_response as a lookup fitted from the pairs (module docstring): ``blend``
    moves the sim's colour change towards the lookup's; nothing of any one sensor is used."""

    def fitted_numbers(self, base: Base) -> int:
        """``blend`` and the lookup's every coefficient (F x 3 x 6, least squares)."""
        columns = response_design(base.depth[:1, :, :2, :2], base.gel_mm).shape[-1]
        return len(self.searched) + 3 * columns

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        if base.lookup is None:
            raise TactileBenchError(
                "optical_response: no fitted lookup (the fit split's pairs were not given)"
            )
        blend = torch.as_tensor(self.full_params(params)["blend"])
        fitted = predict_delta(x.height, base.lookup, base.gel_mm)
        return x.replace(delta=(1 - blend) * x.delta + blend * fitted)


class Registration(Candidate):
    """pose_error as a constant misregistration (module docstring): acts on the ``Base``,
    before the geometry, warping depth, colour change and cached shading alike. Offsets and
    yaw are in image axes (x right, y down), so ``offset_y_mm`` and ``yaw_offset_deg`` have
    the opposite sign of the pose effect's (whose y points up)."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=("jitter_mm", "yaw_jitter_deg"),
            note="constant shift and rotation of the depth against the real frames",
        )
        self.searched = tuple(replace(s, differentiable=True) for s in self.searched)
        self.stochastic = False

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        p = self.full_params(params)
        if all(isinstance(v, float | int) and v == 0 for v in p.values()):
            return x
        half = torch.tensor([base.gel_mm[0] / 2, base.gel_mm[1] / 2])
        yaw = torch.deg2rad(torch.as_tensor(p["yaw_offset_deg"], dtype=torch.float32))
        cos, sin = torch.cos(yaw), torch.sin(yaw)
        shift = torch.stack(
            [torch.as_tensor(p["offset_x_mm"]), torch.as_tensor(p["offset_y_mm"])]
        ).float()
        # output point o (mm) samples the depth at R(-yaw) (o - shift), in [-1, 1] units
        r_inv = torch.stack([torch.stack([cos, sin]), torch.stack([-sin, cos])])
        a = r_inv * half[None, :] / half[:, None]
        b = -(r_inv @ shift) / half
        theta = torch.cat([a, b[:, None]], 1)[None]
        grid = F.affine_grid(theta, [1, 1, base.size, base.size], align_corners=False)

        def warp(t: torch.Tensor) -> torch.Tensor:
            g = grid.expand(len(t), -1, -1, -1)
            return F.grid_sample(t, g, mode="bilinear", padding_mode="border", align_corners=False)

        shading = {1: warp(x._shading[1])} if 1 in x._shading else {}
        # the fit's gradient flows through the colour change; the depth only feeds the sim
        # optics of later geometry, whose kernels work in place (no gradient through them)
        return replace(x, depth=warp(x.depth).detach(), delta=warp(x.delta), _shading=shading)


class PressDepth(Candidate):
    """press_error as a depth scale and offset of each contact (module docstring): acts on
    the ``Base`` before the geometry; its colour change through the user's sim optics."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=("depth_jitter_mm",),
            note="each contact's depth scaled and offset about its peak (no widening)",
        )
        self.searched = tuple(replace(s, differentiable=False) for s in self.searched)
        self.stochastic = False

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        p = self.full_params(params)
        change = (float(p["depth_scale"]) - 1.0) * x.depth.amax((1, 2, 3), keepdim=True)
        change = change + float(p["depth_offset_mm"])
        if not bool(change.abs().gt(0).any()):
            return x
        depth = torch.where(x.depth > 0, (x.depth + change).clamp(min=0.0), x.depth)
        shading = x.sim_change(depth)
        delta = x.delta + shading - x.shading(1)
        return replace(x, depth=depth, delta=delta, _shading={1: shading})


class ToneCurve(Candidate):
    """gamma_white_balance: the camera's curve acts on the light the real sensor saw, the
    measured no-contact frame undone through the curve, plus the contact's change."""

    tone_curve = True

    def undo(self, frame: torch.Tensor, params: Mapping[str, ParamValue]) -> torch.Tensor:
        return self.effect.invert(frame, self.full_params(params))


class StoredJpeg(Candidate):
    """jpeg at the sensor's native frame (the effect's codec) or at the size the frames are
    stored at (``stored_size`` 1: a dataset that wrote its resized frames as JPEG files, by
    the encoder datasets are written with: libjpeg through Pillow)."""

    codec = True

    def __init__(self, effect: Effect, **kwargs: Any) -> None:
        super().__init__(effect, **kwargs)
        self.searched = self.searched + (Searched("stored_size", 0.0, 1.0, 0.0, False, True),)

    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
        base: Base,
    ) -> Any:
        if float(params.get("stored_size", 0.0)) < 0.5:
            return self.effect.apply(x, self.full_params(params), generator, ctx)
        quality = float(self.full_params(params)["quality"])
        if quality >= 100.0 or not len(x):
            return x
        return libjpeg(x, quality)


def _deterministic_geometry(effects: Mapping[str, Any]) -> dict[str, Any]:
    """The geometry effects of ``effects`` the lookup can be refitted under (no draws)."""
    return {
        n: dict(p)
        for n, p in effects.items()
        if CANDIDATES[n].acts_on == "geometry"
        and not CANDIDATES[n].stochastic
        and not CANDIDATES[n].latent_grid
    }


def lookup_for(base: Base, geometry: Mapping[str, Mapping[str, ParamValue]]) -> torch.Tensor:
    """The response lookup (F, 3, 6) fitted on the fit split under ``geometry``: cached."""
    if base.lookup_fit is None:
        raise TactileBenchError(
            "optical_response: no fitted lookup (the fit split's pairs were not given)"
        )
    key = json.dumps(
        {n: {k: float(v) for k, v in sorted(p.items())} for n, p in sorted(geometry.items())}
    )
    if key not in base.lookup_cache:
        depth, target = base.lookup_fit
        if geometry:
            flat = Base(
                depth, torch.zeros_like(target), base.background, base.measured, gel_mm=base.gel_mm
            )
            height, _ = _geometry(flat, geometry, None, base.context(False), shade=False)
        else:
            height = depth
        with torch.no_grad():
            try:
                table = torch.as_tensor(fit_response(height, target, base.gel_mm))
            except ValueError:  # no contact in the fit split: the lookup predicts no change
                n_cols = response_design(height[:1, :, :2, :2], base.gel_mm).shape[-1]
                table = torch.zeros(n_cols // 6, 3, 6)
        base.lookup_cache[key] = table.float()
    return base.lookup_cache[key]


_SPECIAL: dict[str, Any] = {
    # the codec rounds quality to a whole number and its tables change at every step: the
    # gap drops sharply only at the exact value, so every whole value is tried
    "jpeg": lambda e: StoredJpeg(e, note="quality searched value by value", integer=("quality",)),
    "gamma_white_balance": ToneCurve,
    "shear_smear": lambda e: LatentSmear(e, note="slip direction chosen per pair (latent)"),
    "gel_wear": MeasuredWear,
    "pose_error": Registration,
    "press_error": PressDepth,
    "optical_response": lambda e: FittedResponse(e, note="lookup fitted from the fit split"),
    "surface_texture": lambda e: ContactTexture(
        e, note="beads along image axes (no contact yaw)", fixed={"bead_angle_deg": 0.0}
    ),
}
CANDIDATES: dict[str, Candidate] = {
    n: _SPECIAL.get(n, Candidate)(EFFECTS[n]) for n in DEFAULT_CANDIDATES
}


def get_candidate(name: str) -> Candidate:
    if name not in CANDIDATES:
        why = NOT_CANDIDATES.get(name, "unknown effect")
        raise TactileBenchError(
            f"{name!r} is not a diagnosis candidate ({why}); candidates: {', '.join(CANDIDATES)}"
        )
    return CANDIDATES[name]


def bake_fixed(base: Base, effects: Mapping[str, Mapping[str, ParamValue]]) -> Base:
    """``base`` with (deterministic) pose and geometry ``effects`` applied: a new depth and
    colour change, so the effects acting after them can be fitted without re-rendering them
    every step."""
    ctx = base.context()
    for n in [n for n in EFFECT_ORDER if n in effects and CANDIDATES[n].acts_on == "pose"]:
        base = CANDIDATES[n].apply(base, effects[n], None, ctx, base)
    height, delta = _geometry(base, effects, None, ctx)
    baked = {**base.baked, **_deterministic_geometry(effects)}
    return replace(base, depth=height, delta=delta, _shading={}, baked=baked)


def _geometry(
    base: Base,
    effects: Mapping[str, Mapping[str, ParamValue]],
    generator: torch.Generator | None,
    ctx: EffectContext,
    shade: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(height, delta) after the geometry effects among ``effects``, in catalogue order
    (``shade=False``: the height only; delta is returned unchanged)."""
    names = [n for n in EFFECT_ORDER if n in effects and CANDIDATES[n].acts_on == "geometry"]
    if not names:
        return base.depth, base.delta
    factor = max(CANDIDATES[n].oversample for n in names)
    h = base.depth_at(factor)
    for n in names:
        h = CANDIDATES[n].apply(h, effects[n], generator, ctx, base)
    height = h.clamp(min=0.0)
    height = F.avg_pool2d(height, factor) if factor > 1 else height
    if not shade:
        return height, base.delta
    return height, base.delta + base.sim_change(height) - base.shading(factor)


def render(
    base: Base,
    effects: Mapping[str, Mapping[str, ParamValue]],
    generator: torch.Generator | None = None,
    stochastic: bool = True,
) -> torch.Tensor:
    """Sim images (N, 3, S, S), 0..255, of ``base`` with ``effects`` added in catalogue order."""
    for name in effects:
        get_candidate(name).check(effects[name])
    names = [n for n in EFFECT_ORDER if n in effects]
    ctx = base.context(stochastic)
    if "optical_response" in effects:
        base = replace(
            base,
            lookup=lookup_for(
                base, {**base.baked, **_deterministic_geometry({n: effects[n] for n in names})}
            ),
        )
    for n in [n for n in names if CANDIDATES[n].acts_on == "pose"]:
        base = CANDIDATES[n].apply(base, effects[n], generator, ctx, base)
    height, delta = _geometry(base, effects, generator, ctx)
    # the light the sim saw (its own no-contact frame) goes through the candidate sensor
    # with and without the contact; the measured frame already went through the real one,
    # so only the difference (the contact's change as the sensor sees it) is added to it
    ref = base.sim_frame
    contact = _through_sensor(base, names, effects, new_scene(height, ref, delta), ctx)
    if contact.shape[0] != len(base):
        contact = contact.expand(len(base), -1, -1, -1)
    flat_height = torch.zeros(1, 1, base.size, base.size)
    flat = _through_sensor(base, names, effects, new_scene(flat_height, ref), ctx)
    measured = base.background
    image = measured + (contact - flat)
    for n in [n for n in names if CANDIDATES[n].acts_on == "camera"]:
        cand, p = CANDIDATES[n], effects[n]
        if cand.tone_curve:  # at the real light's level: the measured frame undone
            light = cand.undo(measured, p) + (image - measured)  # the change, noise and all
            image = cand.apply(light, p, generator, ctx, base)
            flat = cand.apply(flat, p, None, ctx, base)
        elif cand.codec:  # around the sim's own (uncompressed) frame: the change it codes
            coded = cand.apply(flat + (image - measured), p, generator, ctx, base)
            image = measured + coded - cand.apply(flat, p, None, ctx, base)
        elif cand.whole_frame:  # per-frame draws: the composite as a whole
            image = cand.apply(image, p, generator, ctx, base)
    return image.clamp(0.0, 255.0)


def _through_sensor(
    base: Base,
    names: list[str],
    effects: Mapping[str, Mapping[str, ParamValue]],
    scene: Any,
    ctx: EffectContext,
) -> torch.Tensor:
    """A scene through the optics and the camera effects that are linear in the light
    (blur, vignetting), in catalogue order: deterministic, no draws. Tone curves, codecs
    and per-frame noise act on the composite (``render``)."""
    for n in [n for n in names if CANDIDATES[n].acts_on == "optics"]:
        scene = CANDIDATES[n].apply(scene, effects[n], None, ctx, base)
    image = scene.composite()
    for n in names:
        cand = CANDIDATES[n]
        if cand.acts_on == "camera" and not (cand.whole_frame or cand.tone_curve or cand.codec):
            image = cand.apply(image, effects[n], None, ctx, base)
    return image


def render_background(base: Base, effects: Mapping[str, Mapping[str, ParamValue]]) -> torch.Tensor:
    """The candidate simulator's no-contact frame (3, S, S): zero depth, no per-frame noise."""
    flat = replace(
        base,
        depth=torch.zeros(1, 1, base.size, base.size),
        delta=torch.zeros(1, 3, base.size, base.size),
        _shading={},
        latent={},
    )
    return render(flat, effects, None, stochastic=False)[0]
