"""Candidate effects: how each catalogue effect is added to paired sim data, from the data only.

The candidate simulator starts from what paired data hold, never from a sensor profile:

- the **base scene** of a pair is its sim image split into background and colour change:
  ``background`` = ``data.sim_background`` when given (else ``data.background``: the sim
  was then composited onto the measured frame), ``delta = sim - background``, height =
  the pair's depth, unit gain; composited with no effect it is the sim image exactly;
- **geometry** effects change the height (sub-pixel texture at 2x the image size,
  area-averaged back as a camera integrates), and their colour change is re-rendered
  *linearly*:
  ``delta + SimOptics(h') - SimOptics(h)`` (noise-free). Exact for the built-in simulator,
  a first-order model for a user's own one;
- **optics** effects act on that scene, **camera** effects on its composite, as in
  ``SurrogateDigit``.

Every parameter not searched is held at its **neutral** value: ``Effect.apply`` fills
missing parameters with *defaults*, the very values the default surrogate profile uses, so
they are never left to it. Nothing here reads ``Param.default``.

Left out or modelled differently, and why:

- ``pose_error``, ``press_error`` (pose stage) move or deepen the contact itself: they need
  the contact mesh and pose, which paired images lack. Not candidates; the diagnosis then
  reports their gap as unexplained (``validate-diagnosis`` plants them to check that).
- ``gel_wear``: dust and scratches sit where the unit's random draw (``unit_seed``) put
  them, which no parameter search can find. They also darken the measured no-contact frame,
  so the candidate reads them from the data: the fine-scale transmission
  ``fine(data.background) / fine(base background)`` (``fine(x) = x / blur(x)``),
  raised to ``measured_wear`` in [0, 1]; only ``coating_wear`` (the worn centre's lost
  response, centred) is an effect parameter searched.
- ``surface_texture``: the beads follow each contact's yaw, which paired data lack: they
  are laid along image axes (``bead_angle_deg`` held at 0), and only where the depth is
  positive (off the contact the true height below the gel is unknown).
- ``shear_smear``: the slip direction is random per contact, so it is a per-pair latent
  (the gap takes the best of 8 directions pair by pair); the length is the shared parameter.
- ``jpeg``: quality is searched value by value (the codec rounds it, and the gap drops only
  at the exact value).
- Geometry parameters are searched without gradients: their change reaches the image
  through the simulator's optics, a black box.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.paired import PairedData
from tactile_bench.effects import EFFECT_ORDER, EFFECTS, Effect, EffectContext
from tactile_bench.effects.base import ParamValue, gaussian_blur
from tactile_bench.effects.optics import new_scene
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics

GEL = GelSpec()  # paired data carry no gel size: a DIGIT's 18 x 24 mm view
OVERSAMPLE = 2  # geometry effects act at this multiple of the image size
NOT_CANDIDATES: dict[str, str] = {
    "pose_error": "needs the contact pose and mesh, which paired images lack",
    "press_error": "needs the contact pose and mesh, which paired images lack",
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
    delta: torch.Tensor  # (N, 3, S, S) sim - background
    background: torch.Tensor  # (1, 3, S, S) what the sim was composited onto
    measured: torch.Tensor  # (3, S, S) the real sensor's no-contact frame
    _shading: dict[int, torch.Tensor] = field(default_factory=dict, repr=False)
    latent: dict[str, torch.Tensor] = field(default_factory=dict)  # per-pair hidden values

    def __len__(self) -> int:
        return len(self.depth)

    @property
    def size(self) -> int:
        return int(self.depth.shape[-1])

    def subset(self, idx: torch.Tensor) -> Base:
        shading = {k: v[idx] for k, v in self._shading.items()}
        latent = {k: v[idx] for k, v in self.latent.items()}
        return Base(
            self.depth[idx], self.delta[idx], self.background, self.measured, shading, latent
        )

    def with_latent(self, name: str, value: float) -> Base:
        """The same pairs with ``name``'s hidden per-pair value set to ``value`` for all."""
        latent = {**self.latent, name: torch.full((len(self),), float(value))}
        return Base(self.depth, self.delta, self.background, self.measured, self._shading, latent)

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
            self._shading[factor] = sim_shading(height, self.background)
        return self._shading[factor]

    def precompute(self) -> Base:
        """Cache the shading at every factor the candidates use (before taking subsets)."""
        for factor in {1, OVERSAMPLE}:
            self.shading(factor)
        return self


def make_base(data: PairedData, idx: torch.Tensor | None = None) -> Base:
    """The base scene of the pairs at ``idx`` (all by default)."""
    if idx is not None:
        data = data.subset(idx)
    bg = data.sim_background if data.sim_background is not None else data.background
    bg = bg.float()[None]
    return Base(data.depth.float(), data.sim.float() - bg, bg, data.background.float())


def sim_shading(height: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """SimOptics' noise-free colour change of ``height`` over ``background`` (as the surrogate)."""
    gel = GelSpec(GEL.width_mm, GEL.height_mm, height.shape[-1], 1)
    bg = background.reshape(3, *background.shape[-2:])
    return SimOptics().render(height, bg, None, gel) - bg


def fine_scale(x: torch.Tensor, sigma_px: float = 3.0) -> torch.Tensor:
    """``x / blur(x)``: what a smooth field lacks at scales below ``sigma_px`` (dust, scratches)."""
    s = torch.tensor(sigma_px)
    return x / gaussian_blur(x, s, s).clamp(min=1.0)


class Candidate:
    """How one catalogue effect is searched and applied to a ``Base``.

    ``searched``: the parameters a fit varies (others held at neutral). ``apply`` takes the
    stage's data like ``Effect.apply`` plus the ``Base`` (for data-derived parts).
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
        self.fixed = dict(fixed or {})  # held values of skipped parameters (else neutral)
        skip = tuple(skip) + tuple(self.fixed)
        self.name = effect.name
        self.stage = effect.stage
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
            for diff in [p.name in effect.differentiable and effect.stage != "geometry"]
        )

    latent_grid: tuple[float, ...] = ()  # values of a per-pair hidden variable, tried per pair
    oversample = 1  # geometry at this multiple of the image size (sub-pixel detail: > 1)

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
        ratio = fine_scale(base.measured[None]) / fine_scale(base.background)
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


_SPECIAL: dict[str, Any] = {
    # the codec rounds quality to a whole number and its tables change at every step: the
    # gap drops sharply only at the exact value, so every whole value is tried
    "jpeg": lambda e: Candidate(e, note="quality searched value by value", integer=("quality",)),
    "shear_smear": lambda e: LatentSmear(e, note="slip direction chosen per pair (latent)"),
    "gel_wear": MeasuredWear,
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


def bake_geometry(base: Base, effects: Mapping[str, Mapping[str, ParamValue]]) -> Base:
    """``base`` with (deterministic) geometry ``effects`` applied: a new depth and colour
    change, so later stages can be fitted without re-rendering the geometry every step."""
    height, delta = _geometry(base, effects, None, EffectContext(GEL.width_mm, GEL.height_mm))
    return Base(height, delta, base.background, base.measured)


def _geometry(
    base: Base,
    effects: Mapping[str, Mapping[str, ParamValue]],
    generator: torch.Generator | None,
    ctx: EffectContext,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(height, delta) after the geometry effects among ``effects``, in catalogue order."""
    names = [n for n in EFFECT_ORDER if n in effects and CANDIDATES[n].stage == "geometry"]
    if not names:
        return base.depth, base.delta
    factor = max(CANDIDATES[n].oversample for n in names)
    h = base.depth_at(factor)
    for n in names:
        h = CANDIDATES[n].apply(h, effects[n], generator, ctx, base)
    height = h.clamp(min=0.0)
    height = F.avg_pool2d(height, factor) if factor > 1 else height
    return height, base.delta + sim_shading(height, base.background) - base.shading(factor)


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
    ctx = EffectContext(GEL.width_mm, GEL.height_mm, stochastic)
    height, delta = _geometry(base, effects, generator, ctx)
    scene = new_scene(height, base.background, delta)
    for n in [n for n in names if CANDIDATES[n].stage == "optics"]:
        scene = CANDIDATES[n].apply(scene, effects[n], generator, ctx, base)
    image = scene.composite()
    if image.shape[0] != len(base):
        image = image.expand(len(base), -1, -1, -1)
    for n in names:
        if CANDIDATES[n].stage == "camera":
            image = CANDIDATES[n].apply(image, effects[n], generator, ctx, base)
    return image.clamp(0.0, 255.0)


def render_background(base: Base, effects: Mapping[str, Mapping[str, ParamValue]]) -> torch.Tensor:
    """The candidate simulator's no-contact frame (3, S, S): zero depth, no per-frame noise."""
    flat = Base(
        torch.zeros(1, 1, base.size, base.size),
        torch.zeros(1, 3, base.size, base.size),
        base.background,
        base.measured,
    )
    return render(flat, effects, None, stochastic=False)[0]
