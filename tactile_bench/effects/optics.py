"""Effects acting on the optics: how the deformed gel turns the LEDs' light into colour.

They act on an ``OpticalScene`` at the render resolution, in the order per-unit background
-> optical response -> LED diffusivity -> shadows -> gel wear. The surrogate starts the
scene from the simulator's shading (``sensor.optics.SimOptics``: three ideal point lights,
Phong), so with every optics effect neutral it shades like the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache

import torch
import torch.nn.functional as F

from tactile_bench.effects._optics_fit import N_HARM, N_MAG
from tactile_bench.effects.base import (
    Effect,
    EffectContext,
    OpticalScene,
    Param,
    ParamValue,
    as_tensor,
    per_sub_batch,
    scalar,
)
from tactile_bench.effects.kernels import pixel_grid, surface_gradient
from tactile_bench.effects.sensors import sensor_fit

# Depth (mm) over which a contact's flat-slope colour offset fades in.
CONTACT_OFFSET_MM = 0.05


def new_scene(
    height: torch.Tensor, background: torch.Tensor, delta: torch.Tensor | None = None
) -> OpticalScene:
    """A scene over ``background`` (3|N, 3, H, W) under unit gain, on ``height``'s device; no
    colour change by default."""
    n, _, h, w = height.shape
    background = background.to(height.device)
    return OpticalScene(
        height=height,
        background=background if background.dim() == 4 else background[None],
        delta=delta if delta is not None else height.new_zeros(n, 3, h, w),
        gain=height.new_ones(1, 3, 1, 1),
    )


def sensor_optics(sensor: str) -> tuple[torch.Tensor, tuple[float, ...]]:
    """(response weights (F, 3, 6), LED azimuths (deg, R, G, B)) of a registered sensor
    (``effects.sensors``: the DIGIT's from ``_optics_fit``, the GelSights' from
    ``_taxim_fit``, a profile's own); unknown names are an error."""
    fit = sensor_fit(sensor)
    return fit.response_weights, fit.led_azimuth_deg


def response_features(gx: torch.Tensor, gy: torch.Tensor, contact: torch.Tensor) -> torch.Tensor:
    """(*, F) features of the compact model: contact offset, t^j x direction harmonics."""
    r = torch.sqrt(gx**2 + gy**2 + 1e-12)
    t = torch.atan(r) * (2 / math.pi)
    c1, s1 = gx / r, gy / r
    harms = [torch.ones_like(t)]
    ck, sk = c1, s1
    for _ in range(N_HARM):
        harms += [ck, sk]
        ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
    feats = [contact]
    tj = t
    for _ in range(N_MAG):
        feats += [tj * hk for hk in harms]
        tj = tj * t
    return torch.stack(feats, -1)


def position_basis(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.stack([torch.ones_like(u), u, v, u**2, v**2, u * v], -1)


def fitted_response(
    gx: torch.Tensor,
    gy: torch.Tensor,
    u: torch.Tensor,
    v: torch.Tensor,
    contact: torch.Tensor,
    sensor: str = "digit",
) -> torch.Tensor:
    """Real DIGIT colour change (3, *shape) for slope (gx, gy) mm/mm at position (u, v).

    The compact model fitted to Taxim's polycalib (``_optics_fit``): harmonics of the slope
    direction times powers of the slope angle, each with a quadratic position field.
    ``contact`` in [0, 1] scales the flat-contact offset term. Inputs broadcast together.
    """
    gx, gy, u, v, contact = torch.broadcast_tensors(gx, gy, u, v, contact)
    f = response_features(gx, gy, contact)
    pos = position_basis(u, v)
    weights = sensor_optics(sensor)[0]
    return torch.einsum("...f,fcq,...q->c...", f, weights.to(f), pos)


def response_fields(weights: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """(F, 3, H, W): each feature's per-channel position field for ``weights`` (F, 3, 6),
    on ``weights``' device."""
    uu, vv = pixel_grid(h, w, weights.device)
    return torch.einsum("fcq,hwq->fchw", weights, position_basis(uu, vv)).contiguous()


@lru_cache(maxsize=8)
def _response_fields(
    h: int, w: int, sensor: str = "digit", device: torch.device | str = "cpu"
) -> torch.Tensor:
    """A registered sensor's ``response_fields``, cached per size and device (a key stands
    for one set of numbers, ``effects.sensors``: the cache is never stale)."""
    return response_fields(sensor_optics(sensor)[0].to(device), h, w)


def fitted_response_image(
    gx: torch.Tensor, gy: torch.Tensor, contact: torch.Tensor, sensor: str = "digit"
) -> torch.Tensor:
    """A real sensor's colour change (N, 3, H, W) for slope maps (N, H, W) over the view."""
    fields = _response_fields(gx.shape[-2], gx.shape[-1], sensor, gx.device)
    return response_image(gx, gy, contact, fields)


def response_image(
    gx: torch.Tensor, gy: torch.Tensor, contact: torch.Tensor, fields: torch.Tensor
) -> torch.Tensor:
    """Colour change (N, 3, H, W) of the compact model with position ``fields`` (F, 3, H, W)
    for slope maps and contact weights (N, H, W): feature by feature, in place."""
    r = torch.sqrt(gx**2 + gy**2 + 1e-12)
    t = torch.atan(r) * (2 / math.pi)
    c1, s1 = gx / r, gy / r
    harms = [None]  # None stands for the constant harmonic (skips a multiply by ones)
    ck, sk = c1, s1
    for k in range(N_HARM):
        harms += [ck, sk]
        if k < N_HARM - 1:  # the next harmonic, if one is used
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
    out = contact[:, None] * fields[0]
    k, tj = 1, t
    for j in range(N_MAG):
        for hk in harms:
            f = tj if hk is None else tj * hk
            out = out.addcmul_(f[:, None], fields[k])  # in place: no (N, 3, H, W) temporaries
            k += 1
        if j < N_MAG - 1:
            tj = tj * t
    return out


def _real_response(height: torch.Tensor, ctx: EffectContext) -> torch.Tensor:
    gx, gy = surface_gradient(height, ctx)
    contact = (height / CONTACT_OFFSET_MM).clamp(0.0, 1.0)
    return fitted_response_image(gx[:, 0], gy[:, 0], contact[:, 0], ctx.sensor)


class OpticalResponse(Effect):
    name = "optical_response"
    acts_on = "optics"
    description = (
        "A real DIGIT is not three ideal point lights on a Lambertian surface. Light enters "
        "through the gel's edge, scatters in the elastomer and reflects off a semi-specular "
        "coating, so the colour change for a given slope depends on where the pixel is "
        "(distance and angle to each LED), saturates and even reverses at steep slopes, and "
        "leaks between channels. This effect replaces the simulator's shading by a compact "
        "model fitted to a real DIGIT's example-based calibration (Taxim polycalib); ``blend`` "
        "interpolates between the two."
    )
    _src = "../shared/real/digit_polycalib.npz (Taxim calibs/digit/polycalib.npz), fitted"
    params = (Param("blend", "1", 1.0, 0.0, 1.0, 0.0, _src, "0 = simulator shading, 1 = real"),)
    differentiable = ("blend",)

    def _apply(
        self,
        x: OpticalScene,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> OpticalScene:
        # 8 images a pass: the 22 feature maps then stay in cache
        real = per_sub_batch(lambda z: _real_response(z, ctx), x.height, size=8)
        if not isinstance(p["blend"], torch.Tensor) and float(p["blend"]) == 1.0:
            return x.replace(delta=real)  # the simulator's shading is replaced outright
        blend = as_tensor(p["blend"])
        return x.replace(delta=(1 - blend) * x.delta + blend * real)


class LedDiffusivity(Effect):
    name = "led_diffusivity"
    acts_on = "optics"
    description = (
        "Every manufactured DIGIT lights its gel differently: its LEDs come from different "
        "intensity bins, sit slightly differently behind a diffusing edge, and their spectra "
        "overlap the camera's colour filters. Per-LED intensity scales that channel's "
        "background and contact response; diffusion (light arriving from all directions) "
        "flattens the slope contrast; crosstalk mixes each channel's response into the others."
    )
    _bin = "LED luminous-intensity binning, +-15% per bin (e.g. Kingbright APTF1616 RGB datasheet)"
    _dif = "estimate: DIGIT LEDs shine through a diffusing edge (Lambeta et al. 2020, RA-L)"
    _xt = "Bayer CFA spectral overlap of small CMOS sensors, ~5-10% (OV7670 datasheet fig.)"
    params = (
        Param("gain_r", "1", 1.0, 0.5, 1.5, 1.0, _bin, "red LED intensity, relative"),
        Param("gain_g", "1", 0.94, 0.5, 1.5, 1.0, _bin, "green LED intensity, relative"),
        Param("gain_b", "1", 1.06, 0.5, 1.5, 1.0, _bin, "blue LED intensity, relative"),
        Param("diffusion", "1", 0.1, 0.0, 0.9, 0.0, _dif, "diffuse fraction of LED light"),
        Param("crosstalk", "1", 0.06, 0.0, 0.3, 0.0, _xt, "response leaking to other channels"),
    )
    differentiable = tuple(q.name for q in params)

    def _apply(
        self,
        x: OpticalScene,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> OpticalScene:
        like = x.delta
        g = torch.stack([as_tensor(p[k], like) for k in ("gain_r", "gain_g", "gain_b")])
        xt = as_tensor(p["crosstalk"], like)
        eye = torch.eye(3, device=like.device)
        mix = (1 - xt) * eye + xt / 2 * (1 - eye)
        # gain, diffusion and crosstalk on the response as one 3 x 3 colour matrix
        mix = mix * (g * (1 - as_tensor(p["diffusion"], like)))[None, :]
        delta = torch.einsum("ij,njhw->nihw", mix, x.delta)
        return x.replace(background=x.background * g.view(1, 3, 1, 1), delta=delta)


class Shadows(Effect):
    name = "shadows"
    acts_on = "optics"
    description = (
        "The LEDs light the gel from low on its side, so a steep bump of the gel surface "
        "occludes each LED for the surface just beyond it: a dark crescent on the side away "
        "from that LED, in that LED's colour. A point is shadowed when the surface rises "
        "above its line of sight to the LED; the depth of the shadow is the fraction of the "
        "channel's light that comes straight from its LED."
    )
    _el = "estimate: LEDs at the gel edge, ~4 mm high next to an 18 mm gel (DIGIT, Lambeta 2020)"
    _st = "Taxim shadow table (Si & Yuan 2022): shadows reach ~50% of the lit intensity"
    _rc = "covers a 1.1 mm braille dome at 20 deg (1.1 / tan 20 = 3 mm); LED azimuths from the fit"
    params = (
        Param("elevation_deg", "deg", 20.0, 5.0, 60.0, 20.0, _el, "LED elevation over the gel"),
        Param("strength", "1", 0.5, 0.0, 1.0, 0.0, _st, "direct fraction of each LED's light"),
        Param("softness_mm", "mm", 0.05, 0.005, 0.5, 0.05, _st, "penumbra height scale"),
        Param("reach_mm", "mm", 3.0, 0.5, 6.0, 3.0, _rc, "longest shadow searched"),
    )
    differentiable = ("elevation_deg", "strength", "softness_mm")
    steps = 10

    def _apply(
        self,
        x: OpticalScene,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> OpticalScene:
        shadow = per_sub_batch(lambda z: self._shadow(z, p, ctx), x.height, size=16)
        return x.replace(gain=x.gain * (1 - as_tensor(p["strength"]) * shadow))  # (N, 3, H, W)

    def _shadow(
        self, z: torch.Tensor, p: Mapping[str, ParamValue], ctx: EffectContext
    ) -> torch.Tensor:
        elevation = p["elevation_deg"]
        if isinstance(elevation, torch.Tensor):
            tan_el = torch.tan(torch.deg2rad(elevation.float()))
        else:  # a float: keeps the ~30 steps below free of 0-d tensor ops
            tan_el = math.tan(math.radians(elevation))
        reach = scalar(p["reach_mm"])
        dx, dy = ctx.mm_per_px(z)
        pad = math.ceil(reach / min(dx, dy)) + 1
        zp = F.pad(z, (pad, pad, pad, pad), mode="replicate")
        h, w = z.shape[-2:]
        soft = p["softness_mm"]
        grad = (
            z.requires_grad
            or isinstance(tan_el, torch.Tensor)
            or (isinstance(soft, torch.Tensor) and soft.requires_grad)
        )
        masks = []
        azimuths = sensor_optics(ctx.sensor)[1]
        if not grad:  # write each LED's running max into its channel, no temporaries
            occ = z.new_empty(z.shape[0], len(azimuths), h, w)
            tmp = torch.empty_like(z)
        for led, az in enumerate(azimuths):
            a = math.radians(az)
            sight = None  # highest rise of the surface above the line of sight to this LED
            seen = set()
            for k in range(1, self.steps + 1):
                t = reach * k / self.steps
                i, j = round(t * math.sin(a) / dy), round(t * math.cos(a) / dx)
                if (i, j) in seen:  # the same pixel again: the same term of the max
                    continue
                seen.add((i, j))
                ahead = zp[..., pad + i : pad + i + h, pad + j : pad + j + w]
                run = math.hypot(i * dy, j * dx)  # the distance actually sampled
                if grad:
                    sight = _running_max(sight, ahead - run * tan_el)
                elif sight is None:
                    sight = torch.sub(ahead, run * tan_el, out=occ[:, led : led + 1])
                else:
                    torch.maximum(sight, torch.sub(ahead, run * tan_el, out=tmp), out=sight)
            masks.append(sight)
        if grad:
            occ = torch.cat(masks, 1) - z
            return (occ / as_tensor(p["softness_mm"])).clamp(0.0, 1.0)
        return occ.sub_(z).div_(scalar(p["softness_mm"])).clamp_(0.0, 1.0)


def _running_max(acc: torch.Tensor | None, x: torch.Tensor) -> torch.Tensor:
    """max(acc, x); into ``acc`` in place when autograd is not recording (no new tensor)."""
    if acc is None:
        return x
    if acc.requires_grad or x.requires_grad:
        return torch.maximum(acc, x)
    return torch.maximum(acc, x, out=acc)


class UnitBackground(Effect):
    name = "unit_background"
    acts_on = "optics"
    description = (
        "Each unit's no-contact frame differs from the one the simulator composites onto: "
        "the LED board and gel sit a little shifted and turned, and the coating's tint "
        "varies. The field is moved and rotated in the gel plane and tinted per channel; the "
        "contact response is untouched (that is led_diffusivity's job)."
    )
    _src = "estimate: assembly tolerance ~0.5 mm / few deg and coating tint spread between units"
    params = (
        Param("shift_x_mm", "mm", 0.4, -3.0, 3.0, 0.0, _src, "field shift along x"),
        Param("shift_y_mm", "mm", -0.3, -3.0, 3.0, 0.0, _src, "field shift along y"),
        Param("rotation_deg", "deg", 2.0, -20.0, 20.0, 0.0, _src, "field rotation"),
        Param("tint_r", "1", 1.03, 0.7, 1.3, 1.0, _src, "red tint of the field"),
        Param("tint_g", "1", 0.98, 0.7, 1.3, 1.0, _src, "green tint of the field"),
        Param("tint_b", "1", 1.02, 0.7, 1.3, 1.0, _src, "blue tint of the field"),
    )
    differentiable = tuple(q.name for q in params)

    def _apply(
        self,
        x: OpticalScene,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> OpticalScene:
        bg = x.background
        n, _, h, w = bg.shape
        uu, vv = pixel_grid(h, w, bg.device)
        xm, ym = uu * ctx.width_mm / 2, vv * ctx.height_mm / 2
        a = torch.deg2rad(as_tensor(p["rotation_deg"], bg))
        # sample the field where this unit's pixel came from: inverse rotate, then unshift
        xs = torch.cos(a) * xm + torch.sin(a) * ym - as_tensor(p["shift_x_mm"])
        ys = -torch.sin(a) * xm + torch.cos(a) * ym - as_tensor(p["shift_y_mm"])
        grid = torch.stack([xs / (ctx.width_mm / 2), ys / (ctx.height_mm / 2)], -1)
        warped = F.grid_sample(
            bg,
            grid.expand(n, h, w, 2),
            mode="bilinear",
            padding_mode="border",
            align_corners=False,
        )
        tint = torch.stack([as_tensor(p[k], bg) for k in ("tint_r", "tint_g", "tint_b")])
        return x.replace(background=warped * tint.view(1, 3, 1, 1))


class GelWear(Effect):
    name = "gel_wear"
    acts_on = "optics"
    description = (
        "A used gel carries dust specks and scratches in its coating that block light, and "
        "its centre, where most contacts land, has a thinner reflective coating that responds "
        "less. These belong to the unit, not the frame: they sit at the same place in every "
        "image and in the no-contact frame (drawn from ``unit_seed``)."
    )
    _src = "estimate: a lab-used gel after weeks of contacts (few specks/cm2, 1-3 scratches)"
    params = (
        Param("dust_per_cm2", "1/cm2", 3.0, 0.0, 50.0, 0.0, _src, "dust speck density"),
        Param("dust_size_mm", "mm", 0.08, 0.02, 0.5, 0.08, _src, "speck radius (sigma)"),
        Param("dust_opacity", "1", 0.4, 0.0, 1.0, 0.0, _src, "light blocked at a speck centre"),
        Param("scratches", "1", 2.0, 0.0, 10.0, 0.0, _src, "number of scratches", integer=True),
        Param("scratch_opacity", "1", 0.15, 0.0, 1.0, 0.0, _src, "light blocked on a scratch"),
        Param("coating_wear", "1", 0.1, 0.0, 0.8, 0.0, _src, "response lost at the worn centre"),
        Param("unit_seed", "1", 1.0, 0.0, 1e6, 1.0, "per-unit draw", "which unit", integer=True),
    )
    differentiable = ("dust_opacity", "scratch_opacity", "coating_wear")

    def _apply(
        self,
        x: OpticalScene,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> OpticalScene:
        h, w = x.delta.shape[-2:]
        fitted = any(isinstance(v, torch.Tensor) and v.requires_grad for v in p.values())
        if fitted:
            transmission, response = _wear_fields(h, w, ctx.width_mm, ctx.height_mm, p)
        else:  # a unit's wear is fixed: compute it once per size and parameter set
            key = tuple((k, scalar(v)) for k, v in sorted(p.items()))
            transmission, response = _cached_wear_fields(h, w, ctx.width_mm, ctx.height_mm, key)
        device = x.delta.device
        return x.replace(gain=x.gain * transmission.to(device), delta=x.delta * response.to(device))


@lru_cache(maxsize=8)
def _cached_wear_fields(
    h: int, w: int, width_mm: float, height_mm: float, key: tuple[tuple[str, float], ...]
) -> tuple[torch.Tensor, torch.Tensor]:
    return _wear_fields(h, w, width_mm, height_mm, dict(key))


def _wear_fields(
    h: int, w: int, width_mm: float, height_mm: float, p: Mapping[str, ParamValue]
) -> tuple[torch.Tensor, torch.Tensor]:
    """(transmission, response), each (H, W): light let through by dust and scratches, and
    the worn coating's share of the contact response; drawn from ``unit_seed``."""
    ctx = EffectContext(width_mm, height_mm)
    g = torch.Generator().manual_seed(int(scalar(p["unit_seed"])))
    uu, vv = pixel_grid(h, w)
    xm, ym = uu * ctx.width_mm / 2, vv * ctx.height_mm / 2
    half = torch.tensor([ctx.width_mm / 2, ctx.height_mm / 2])
    area_cm2 = ctx.width_mm * ctx.height_mm / 100.0
    n_dust = round(scalar(p["dust_per_cm2"]) * area_cm2)
    log_t = torch.zeros(h, w)
    if n_dust:
        c = (torch.rand(n_dust, 2, generator=g) * 2 - 1) * half
        s = scalar(p["dust_size_mm"]) * (0.5 + torch.rand(n_dust, generator=g))
        r2 = (xm - c[:, :1, None]) ** 2 + (ym - c[:, 1:, None]) ** 2
        spot = torch.exp(-0.5 * r2 / s[:, None, None] ** 2)
        opacity = as_tensor(p["dust_opacity"]).clamp(max=0.999)
        log_t = log_t + torch.log1p(-opacity * spot).sum(0)
    n_scr = int(round(scalar(p["scratches"])))
    if n_scr:
        a = (torch.rand(n_scr, 2, generator=g) * 2 - 1) * half
        ang = torch.rand(n_scr, generator=g) * math.pi
        length = 2.0 + 6.0 * torch.rand(n_scr, generator=g)
        d = torch.stack([torch.cos(ang), torch.sin(ang)], 1)
        rel_x, rel_y = xm - a[:, :1, None], ym - a[:, 1:, None]
        along = (rel_x * d[:, :1, None] + rel_y * d[:, 1:, None]).clamp(0.0, None)
        along = torch.minimum(along, length[:, None, None])
        dist2 = (rel_x - along * d[:, :1, None]) ** 2 + (rel_y - along * d[:, 1:, None]) ** 2
        line = torch.exp(-0.5 * dist2 / 0.03**2)
        log_t = log_t + torch.log1p(-as_tensor(p["scratch_opacity"]).clamp(max=0.999) * line).sum(0)
    centre = (torch.rand(2, generator=g) - 0.5) * 2.0  # worn patch within 1 mm of centre
    worn = torch.exp(-0.5 * ((xm - centre[0]) ** 2 + (ym - centre[1]) ** 2) / 4.0**2)
    response = 1 - as_tensor(p["coating_wear"]) * worn
    return torch.exp(log_t), response
