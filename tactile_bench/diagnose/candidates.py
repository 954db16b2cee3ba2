"""Candidate effects: how each catalogue effect is searched and added to a ``PairScene``.

One kind per part of image formation, each with its own ``apply``: a pose candidate moves the
scene's depth and colour change, a geometry candidate the height, an optics candidate the
light leaving the gel (``OpticalScene``), a camera candidate the image. Every parameter not
searched is held at its **neutral** value, never a default. How a kind's effects reach the
image, and why some are modelled apart from the catalogue's effect, is in docs/diagnosis.md.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import ClassVar

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.scene import OVERSAMPLE, PairScene, fine_scale
from tactile_bench.effects import EFFECT_ORDER, EFFECTS, Effect, EffectContext, OpticalScene
from tactile_bench.effects.base import ParamValue, as_tensor
from tactile_bench.effects.camera import libjpeg
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.response_fit import predict_delta, response_design

Params = Mapping[str, ParamValue]
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

    def from_unit(self, u: ParamValue) -> ParamValue:
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


def _start(low: float, high: float, neutral: float) -> float:
    """A starting value on the neutral side: neutral nudged 10% of the range inside the box
    (gradients vanish at a bound such as a zero blur or noise)."""
    span = high - low
    return min(max(neutral, low + 0.1 * span), high - 0.1 * span)


class Candidate:
    """How one catalogue effect is searched: ``searched`` holds the parameters a fit varies
    (the others neutral, or ``fixed``); each kind below says how it is applied."""

    acts_on: ClassVar[str]
    latent_grid: ClassVar[tuple[float, ...]] = ()  # per-pair hidden values, tried per pair
    oversample: ClassVar[int] = 1  # geometry at this multiple of the image size

    def __init__(
        self,
        effect: Effect,
        skip: tuple[str, ...] = (),
        note: str = "",
        fixed: Mapping[str, float] | None = None,
        integer: tuple[str, ...] = (),
    ) -> None:
        self.effect = effect
        self.name = effect.name
        self.stochastic = effect.stochastic
        self.note = note
        self.fixed = dict(fixed or {})  # held values of skipped parameters (else neutral)
        skip = tuple(skip) + tuple(self.fixed)
        # geometry reaches the image through the user's sim optics, a black box: searched
        # without gradients
        differentiable = set(effect.differentiable) if effect.acts_on != "geometry" else set()
        self.searched = tuple(
            Searched(
                p.name,
                p.low,
                p.high,
                _start(p.low, p.high, p.neutral),
                p.name in differentiable,
                p.integer or p.name in integer,
            )
            for p in effect.params
            if p.name not in skip
        )

    def fitted_numbers(self, scene: PairScene) -> int:
        """How many numbers a fit of this candidate sets from the data (its searched
        parameters, plus any table or per-pair value it fits): its freedom to absorb a gap."""
        return len(self.searched) + len(scene) * bool(self.latent_grid)

    def full_params(self, params: Params) -> dict[str, ParamValue]:
        """Every effect parameter: the given ones, neutral for the rest (never the defaults)."""
        out: dict[str, ParamValue] = {**self.effect.neutral_params(), **self.fixed}
        out.update({k: v for k, v in params.items() if k in out})
        return out

    def check(self, params: Params) -> None:
        known = {p.name for p in self.effect.params} | {s.name for s in self.searched}
        bad = sorted(set(params) - known)
        if bad:
            raise TactileBenchError(
                f"candidate {self.name!r}: unknown parameter {bad[0]!r}; known: {sorted(known)}"
            )


# ----------------------------------------------------------------------------- pose
class PoseCandidate(Candidate, ABC):
    """Acts on the scene before the geometry: its depth and colour change together. Fitted
    as constants of the pairs (the per-contact jitter is not searched)."""

    acts_on = "pose"

    def __init__(self, effect: Effect, skip: tuple[str, ...], note: str) -> None:
        super().__init__(effect, skip=skip, note=note)
        self.stochastic = False

    @abstractmethod
    def apply(self, scene: PairScene, params: Params) -> PairScene: ...


class Registration(PoseCandidate):
    """pose_error as a constant misregistration: the depth and colour change warped by a
    shift (mm) and a rotation about the view's centre, in image axes (y down, so
    ``offset_y_mm`` and ``yaw_offset_deg`` have the opposite sign of the pose effect's)."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=("jitter_mm", "yaw_jitter_deg"),
            note="constant shift and rotation of the depth against the real frames",
        )
        self.searched = tuple(replace(s, differentiable=True) for s in self.searched)

    def apply(self, scene: PairScene, params: Params) -> PairScene:
        p = self.full_params(params)
        if all(isinstance(v, float | int) and v == 0 for v in p.values()):
            return scene
        like = scene.delta
        half = like.new_tensor([scene.gel_mm[0] / 2, scene.gel_mm[1] / 2])
        yaw = torch.deg2rad(as_tensor(p["yaw_offset_deg"], like))
        cos, sin = torch.cos(yaw), torch.sin(yaw)
        shift = torch.stack([as_tensor(p["offset_x_mm"], like), as_tensor(p["offset_y_mm"], like)])
        # output point o (mm) samples the depth at R(-yaw) (o - shift), in [-1, 1] units
        r_inv = torch.stack([torch.stack([cos, sin]), torch.stack([-sin, cos])])
        a = r_inv * half[None, :] / half[:, None]
        b = -(r_inv @ shift) / half
        theta = torch.cat([a, b[:, None]], 1)[None]
        grid = F.affine_grid(theta, [1, 1, scene.size, scene.size], align_corners=False)

        def warp(t: torch.Tensor) -> torch.Tensor:
            g = grid.expand(len(t), -1, -1, -1)
            return F.grid_sample(t, g, mode="bilinear", padding_mode="border", align_corners=False)

        shading = {1: warp(scene._shading[1])} if 1 in scene._shading else {}
        # the fit's gradient flows through the colour change; the depth only feeds the sim
        # optics of later geometry, whose kernels work in place (no gradient through them)
        return replace(
            scene, depth=warp(scene.depth).detach(), delta=warp(scene.delta), _shading=shading
        )


class PressDepth(PoseCandidate):
    """press_error as a depth scale and offset of each contact about its peak, re-rendered
    with the user's sim optics (a deeper press's wider contact is not modelled)."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=("depth_jitter_mm",),
            note="each contact's depth scaled and offset about its peak (no widening)",
        )
        self.searched = tuple(replace(s, differentiable=False) for s in self.searched)

    def apply(self, scene: PairScene, params: Params) -> PairScene:
        p = self.full_params(params)
        change = (float(p["depth_scale"]) - 1.0) * scene.depth.amax((1, 2, 3), keepdim=True)
        change = change + float(p["depth_offset_mm"])
        if not bool(change.abs().gt(0).any()):
            return scene
        depth = torch.where(scene.depth > 0, (scene.depth + change).clamp(min=0.0), scene.depth)
        shading = scene.sim_change(depth)
        delta = scene.delta + shading - scene.shading(1)
        return replace(scene, depth=depth, delta=delta, _shading={1: shading})


# ----------------------------------------------------------------------------- geometry
class GeometryCandidate(Candidate):
    """Acts on the height (N, 1, H, W) mm at ``oversample`` x the image size; its colour
    change is re-rendered with the user's sim optics (``simulate``)."""

    acts_on = "geometry"

    def apply(
        self,
        height: torch.Tensor,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
        scene: PairScene,
    ) -> torch.Tensor:
        return self.effect.apply(height, self.full_params(params), generator, ctx)


class ContactTexture(GeometryCandidate):
    """surface_texture on the contact only (paired depth is 0 where the object does not
    touch: its height below the gel is unknown), beads along image axes (no contact yaw);
    finer than a pixel, so rendered at ``OVERSAMPLE`` x and area-averaged."""

    oversample = OVERSAMPLE

    def apply(
        self,
        height: torch.Tensor,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
        scene: PairScene,
    ) -> torch.Tensor:
        textured = super().apply(height, params, generator, ctx, scene)
        return torch.where(height > 0, textured, height)


class LatentSmear(GeometryCandidate):
    """shear_smear: each contact's slip direction is unknown, a per-pair latent. Without one
    (``apply_effects``) the effect draws it, as the sensor does; the gap measure takes, pair
    by pair, the best of ``latent_grid`` directions, so only the length is shared."""

    latent_grid = tuple(float(a) for a in range(0, 360, 45))  # deg, image axes

    def apply(
        self,
        height: torch.Tensor,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
        scene: PairScene,
    ) -> torch.Tensor:
        if self.name not in scene.latent:
            return super().apply(height, params, generator, ctx, scene)
        length = float(self.full_params(params)["smear_mm"])
        out = torch.empty_like(height)
        angles = scene.latent[self.name]
        for angle in torch.unique(angles).tolist():
            idx = (angles == angle).nonzero().squeeze(1)
            out[idx] = _smear(height[idx], length, math.radians(angle), ctx, self.effect.steps)
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


# ----------------------------------------------------------------------------- optics
class OpticsCandidate(Candidate):
    """Acts on the light leaving the gel (``OpticalScene``), with and without the contact;
    deterministic (no draws)."""

    acts_on = "optics"

    def apply(
        self, light: OpticalScene, params: Params, ctx: EffectContext, scene: PairScene
    ) -> OpticalScene:
        return self.effect.apply(light, self.full_params(params), None, ctx)


class MeasuredWear(OpticsCandidate):
    """gel_wear: the worn centre (``coating_wear``) searched; dust and scratches, which sit
    where the unit's random draw put them, read from the data: the fine-scale transmission
    ``fine(measured frame) / fine(sim frame)`` raised to ``measured_wear`` in [0, 1]."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(
            effect,
            skip=tuple(p.name for p in effect.params if p.name != "coating_wear"),
            note="dust and scratches read from the measured no-contact frame (measured_wear)",
        )
        self.searched = self.searched + (Searched("measured_wear", 0.0, 1.0, 0.1, True),)

    def apply(
        self, light: OpticalScene, params: Params, ctx: EffectContext, scene: PairScene
    ) -> OpticalScene:
        light = super().apply(light, params, ctx, scene)
        strength = params.get("measured_wear", 0.0)
        if isinstance(strength, float | int) and strength == 0:
            return light
        ratio = fine_scale(scene.measured[None]) / fine_scale(scene.sim_frame)
        transmission = ratio.mean(1, keepdim=True).clamp(1e-3, 1.0)
        return light.replace(gain=light.gain * transmission ** as_tensor(strength, light.gain))


class FittedResponse(OpticsCandidate):
    """optical_response as a lookup fitted from the fit split's pairs (colour change against
    surface slope and position, ``sensor.response_fit``): ``blend`` moves the sim's colour
    change towards the lookup's; nothing of any one sensor is used."""

    def fitted_numbers(self, scene: PairScene) -> int:
        """``blend`` and the lookup's every coefficient (F x 3 x 6, least squares)."""
        columns = response_design(scene.depth[:1, :, :2, :2], scene.gel_mm).shape[-1]
        return len(self.searched) + 3 * columns

    def apply(
        self, light: OpticalScene, params: Params, ctx: EffectContext, scene: PairScene
    ) -> OpticalScene:
        if scene.lookup is None:
            raise TactileBenchError(
                "optical_response: no fitted lookup (the fit split's pairs were not given)"
            )
        blend = as_tensor(self.full_params(params)["blend"], light.delta)
        fitted = predict_delta(light.height, scene.lookup, scene.gel_mm)
        return light.replace(delta=(1 - blend) * light.delta + blend * fitted)


# ----------------------------------------------------------------------------- camera
@dataclass(frozen=True)
class Composite:
    """The candidate image, the candidate sensor's no-contact frame (noise-free) and the
    measured one (which went through the real camera): what camera steps after the linear
    ones act on."""

    image: torch.Tensor
    flat: torch.Tensor
    measured: torch.Tensor


class CameraCandidate(Candidate):
    """A camera effect linear in the light (blur, vignetting): the sim's frame is taken
    through it with and without the contact, and only the difference is added to the
    measured frame (which already went through the real camera)."""

    acts_on = "camera"
    #: it acts on the whole frame, so the no-contact frame shows it (``diagnose.no_contact``)
    on_no_contact_frame: ClassVar[bool] = True

    def through_sensor(
        self, image: torch.Tensor, params: Params, ctx: EffectContext
    ) -> torch.Tensor:
        return self.effect.apply(image, self.full_params(params), None, ctx)

    def on_composite(
        self,
        frames: Composite,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Composite:
        return frames


class NonlinearCamera(CameraCandidate):
    """A camera step that is not linear in the light: it acts on the composite."""

    on_no_contact_frame = False  # modelled on the composite, not on the sim's frame alone

    def through_sensor(
        self, image: torch.Tensor, params: Params, ctx: EffectContext
    ) -> torch.Tensor:
        return image

    def effect_on(
        self,
        image: torch.Tensor,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        return self.effect.apply(image, self.full_params(params), generator, ctx)


class PerFrameNoise(NonlinearCamera):
    """camera_noise: drawn anew for every frame, and a measured frame holds no draw of this
    frame's, so it acts on the composite as a whole."""

    def on_composite(
        self,
        frames: Composite,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Composite:
        return replace(frames, image=self.effect_on(frames.image, params, generator, ctx))


class ToneCurve(NonlinearCamera):
    """gamma_white_balance: the curve acts on the light the real sensor saw (the measured
    frame undone through the curve) plus the contact's change."""

    def undo(self, frame: torch.Tensor, params: Params) -> torch.Tensor:
        return self.effect.invert(frame, self.full_params(params))

    def on_composite(
        self,
        frames: Composite,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Composite:
        light = self.undo(frames.measured, params) + (frames.image - frames.measured)
        image = self.effect_on(light, params, generator, ctx)
        return replace(frames, image=image, flat=self.effect_on(frames.flat, params, None, ctx))


class StoredJpeg(NonlinearCamera):
    """jpeg at the sensor's native frame (the effect's codec) or at the size the frames are
    stored at (``stored_size`` 1: libjpeg through Pillow, as datasets write their files).
    A codec acts around the sim's own uncompressed frame; its coded difference is added to
    the measured frame (coding that again would compress it twice). Quality is searched
    value by value: the gap drops only at the exact value."""

    def __init__(self, effect: Effect) -> None:
        super().__init__(effect, note="quality searched value by value", integer=("quality",))
        self.searched = self.searched + (Searched("stored_size", 0.0, 1.0, 0.0, False, True),)

    def effect_on(
        self,
        image: torch.Tensor,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        if float(params.get("stored_size", 0.0)) < 0.5:
            return super().effect_on(image, params, generator, ctx)
        quality = float(self.full_params(params)["quality"])
        if quality >= 100.0 or not len(image):
            return image
        return libjpeg(image, quality)

    def on_composite(
        self,
        frames: Composite,
        params: Params,
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Composite:
        change = frames.image - frames.measured
        coded = self.effect_on(frames.flat + change, params, generator, ctx)
        coded_flat = self.effect_on(frames.flat, params, None, ctx)
        return replace(frames, image=frames.measured + coded - coded_flat)


# ----------------------------------------------------------------------------- registry
_MODELLED_APART: dict[str, Candidate] = {
    "pose_error": Registration(EFFECTS["pose_error"]),
    "press_error": PressDepth(EFFECTS["press_error"]),
    "surface_texture": ContactTexture(
        EFFECTS["surface_texture"],
        note="beads along image axes (no contact yaw)",
        fixed={"bead_angle_deg": 0.0},
    ),
    "shear_smear": LatentSmear(
        EFFECTS["shear_smear"], note="slip direction chosen per pair (latent)"
    ),
    "gel_wear": MeasuredWear(EFFECTS["gel_wear"]),
    "optical_response": FittedResponse(
        EFFECTS["optical_response"], note="lookup fitted from the fit split"
    ),
    "camera_noise": PerFrameNoise(EFFECTS["camera_noise"]),
    "gamma_white_balance": ToneCurve(EFFECTS["gamma_white_balance"]),
    "jpeg": StoredJpeg(EFFECTS["jpeg"]),
}
_KIND: dict[str, type[Candidate]] = {
    "geometry": GeometryCandidate,
    "optics": OpticsCandidate,
    "camera": CameraCandidate,
}
CANDIDATES: dict[str, Candidate] = {
    n: _MODELLED_APART.get(n) or _KIND[EFFECTS[n].acts_on](EFFECTS[n]) for n in DEFAULT_CANDIDATES
}


def get_candidate(name: str) -> Candidate:
    if name not in CANDIDATES:
        why = NOT_CANDIDATES.get(name, "unknown effect")
        raise TactileBenchError(
            f"{name!r} is not a diagnosis candidate ({why}); candidates: {', '.join(CANDIDATES)}"
        )
    return CANDIDATES[name]
