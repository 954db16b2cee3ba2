"""Effects acting on the geometry: what happens to the surface between the object and the gel.

They act on the signed height (N, 1, H, W) in mm (positive inside the gel), at the render
resolution, in the order object texture -> elastic spread -> shear smear. Where the elastic
spread has displaced the gel the map holds the gel surface (>= 0); the camera sees its
positive part.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
import torch.nn.functional as F

from tactile_bench.effects.base import (
    Draw,
    Effect,
    EffectContext,
    Param,
    ParamValue,
    as_tensor,
    per_sub_batch,
    scalar,
)
from tactile_bench.effects.draws import randn
from tactile_bench.effects.kernels import gaussian_blur, pixel_grid


class SurfaceTexture(Effect):
    name = "surface_texture"
    acts_on = "geometry"
    stochastic = True
    description = (
        "A 3D-printed braille block is not its mesh. The top skin carries raster beads "
        "(rounded ridges one nozzle width apart), the domes are built as terraces one layer "
        "high, and the plastic has micro-roughness. The gel resolves tens of micrometres, "
        "so the real contact shows ridges and steps the simulated depth lacks. Beads follow "
        "the block's yaw; their phase and the roughness differ between contacts."
    )
    _fdm = "FDM defaults: 0.4 mm nozzle, 0.1 mm layers (Prusa/Ultimaker slicer profiles)"
    _ra = "FDM top-surface roughness Ra 5-15 um (Alsoufi & Elsayed 2017, Rapid Prototyping J.)"
    params = (
        Param("bead_amp_mm", "mm", 0.01, 0.0, 0.1, 0.0, _ra, "raster bead peak-to-valley / 2"),
        Param("bead_pitch_mm", "mm", 0.4, 0.1, 2.0, 0.4, _fdm, "raster bead spacing"),
        Param("bead_angle_deg", "deg", 45.0, -90.0, 90.0, 45.0, _fdm, "raster angle on block"),
        Param("layer_mm", "mm", 0.1, 0.02, 0.4, 0.1, _fdm, "layer height of the terraces"),
        Param("terrace", "1", 0.6, 0.0, 1.0, 0.0, _fdm, "terrace strength (1 = flat steps)"),
        Param("roughness_mm", "mm", 0.004, 0.0, 0.05, 0.0, _ra, "RMS micro-roughness"),
        Param("roughness_corr_mm", "mm", 0.1, 0.02, 1.0, 0.1, _ra, "roughness correlation"),
    )
    differentiable = ("bead_amp_mm", "terrace", "roughness_mm")

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        return [("rand", (n,)), ("randn", (n, 1, *render_hw))]

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        n, _, h, w = x.shape
        # drawn on the CPU (the same numbers on every device), then moved to the height's
        phase = (torch.rand(n, generator=generator) * 2 * math.pi).to(x.device)
        rough = randn((n, 1, h, w), generator).to(x.device)
        if not ctx.stochastic:
            phase, rough = phase * 0, rough * 0
        yaw = ctx.yaw_deg if ctx.yaw_deg is not None else torch.zeros(n)
        yaw = yaw.detach().float().to(x.device)
        ang = torch.deg2rad(as_tensor(p["bead_angle_deg"], x).detach() + yaw)
        return per_sub_batch(lambda *a: self._texture(*a, p, ctx), x, ang, phase, rough)

    @staticmethod
    def _texture(
        x: torch.Tensor,
        ang: torch.Tensor,
        phase: torch.Tensor,
        rough: torch.Tensor,
        p: Mapping[str, ParamValue],
        ctx: EffectContext,
    ) -> torch.Tensor:
        h, w = x.shape[-2:]
        # bead phase pi s / pitch + phase, s = x cos + y sin, is a(x) + b(y): sin(a + b) is a
        # rank-2 product, one small batched matmul instead of a full-size sin
        uu, vv = pixel_grid(h, w, x.device)
        k = math.pi / scalar(p["bead_pitch_mm"])
        a = (uu[0] * ctx.width_mm / 2)[None] * (k * torch.cos(ang))[:, None] + phase[:, None]
        b = (vv[:, 0] * ctx.height_mm / 2)[None] * (k * torch.sin(ang))[:, None]
        sin_b_cos_b = torch.stack([torch.sin(b), torch.cos(b)], -1)  # (N, H, 2)
        cos_a_sin_a = torch.stack([torch.cos(a), torch.sin(a)], 1)  # (N, 2, W)
        bead = torch.bmm(sin_b_cos_b, cos_a_sin_a).abs_()[:, None]  # |sin|, mean 2 / pi
        amp = as_tensor(p["bead_amp_mm"])
        # terraces: steps of one layer measured down from the block's top
        layer = scalar(p["layer_mm"])
        top = x.detach().amax(dim=(2, 3), keepdim=True)
        steps = (top - x).mul_(2 * math.pi / layer)
        steps = steps.sin() if steps.requires_grad else steps.sin_()
        # micro-roughness: white noise low-passed to the correlation length, unit RMS
        dx, dy = ctx.mm_per_px(x)
        corr = scalar(p["roughness_corr_mm"])
        field = gaussian_blur(rough, torch.tensor(corr / dx), torch.tensor(corr / dy))
        rms = torch.linalg.vector_norm(field.detach(), dim=(2, 3), keepdim=True) / math.sqrt(h * w)
        out = torch.addcmul(x - amp * (2 / math.pi), bead, amp)
        out = out.addcmul_(steps, as_tensor(p["terrace"]) * layer / (2 * math.pi))
        return out.addcmul_(field, as_tensor(p["roughness_mm"]) / rms.clamp(min=1e-6))


class ElasticSpread(Effect):
    name = "elastic_spread"
    acts_on = "geometry"
    description = (
        "The gel is a soft elastic layer, not a rigid mould: an indentation pulls the "
        "surrounding surface down with it (Boussinesq: displacement decays with distance "
        "from the load) and rounds sharp edges. Following Taxim, the gel surface is a pyramid "
        "of Gaussian blurs of the penetration with the core of the contact held at the "
        "object's surface; the gel never passes through the object."
    )
    _src = (
        "Taxim (Si & Yuan 2022) Basics/params.py: pyramid kernels 201..5 px at 0.03 mm/px "
        "(largest sigma 30.5 px = 0.9 mm), contact_scale 0.4"
    )
    params = (
        Param("sigma_mm", "mm", 0.9, 0.0, 3.0, 0.0, _src, "largest blur of the pyramid"),
        Param("contact_scale", "1", 0.4, 0.0, 1.0, 0.4, _src, "held core: depth > scale*max"),
    )
    differentiable = ("sigma_mm",)

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        return per_sub_batch(lambda z: self._spread(z, p, ctx), x)

    @staticmethod
    def _spread(x: torch.Tensor, p: Mapping[str, ParamValue], ctx: EffectContext) -> torch.Tensor:
        pen = x.clamp(min=0.0)
        peak = pen.detach().amax(dim=(2, 3), keepdim=True)
        # held core as 0/1 floats: masks by multiply-add are faster than torch.where
        # on CPU and exact here (x * 1 + y * 0 == x)
        core = (pen.detach() > scalar(p["contact_scale"]) * peak).float()
        held = pen * core
        dx, dy = ctx.mm_per_px(x)
        sigma = as_tensor(p["sigma_mm"])
        if not (x.requires_grad or sigma.requires_grad):
            return ElasticSpread._spread_inplace(x, pen, core, held, scalar(sigma), dx, dy)
        free = 1 - core
        z = pen
        level = sigma
        while float(level.detach()) / min(dx, dy) >= 1.0:
            z = torch.addcmul(held, gaussian_blur(z, level / dx, level / dy), free)
            level = level / 2
        # the gel follows the object where they touch (never passes through it) and sags
        # around it; elsewhere the object stays where it was (identity at sigma = 0)
        # z >= 0 (non-negative weights); sign(z) - 1 is 0 where the gel moved, -1 elsewhere
        return torch.maximum(torch.add(z, torch.sign(z) - 1, alpha=1e30), x)

    @staticmethod
    def _spread_inplace(
        x: torch.Tensor,
        pen: torch.Tensor,
        core: torch.Tensor,
        held: torch.Tensor,
        sigma: float,
        dx: float,
        dy: float,
    ) -> torch.Tensor:
        """``_spread`` outside autograd, each step in the blur's fresh output: the same floats
        (``free`` is 0 or 1, so ``b * free + held`` is ``addcmul``'s sum exactly), a third
        fewer allocations and passes over the map."""
        free = core.neg_().add_(1.0)  # core is not used after this
        z = pen
        level = torch.tensor(sigma)
        while float(level) / min(dx, dy) >= 1.0:
            z = gaussian_blur(z, level / dx, level / dy).mul_(free).add_(held)
            level = level / 2
        if z is pen:  # no level ran: keep pen (the caller's clamp) as it was
            z = pen.clone()
        z = z.add_(torch.sign(z).sub_(1.0), alpha=1e30)
        return torch.maximum(z, x, out=z)


class ShearSmear(Effect):
    name = "shear_smear"
    acts_on = "geometry"
    stochastic = True
    description = (
        "A press is never purely normal: lateral compliance of the arm and friction drag the "
        "gel surface sideways while the image is exposed, so the indentation is smeared "
        "along the slip direction. Modelled as the average of the displacement over a "
        "straight slip path of the given length in a random direction per contact."
    )
    _src = (
        "estimate from Taxim Basics/params.py shear_friction 0.07 (tangential/normal) x "
        "~1.5 mm effective gel compression"
    )
    params = (Param("smear_mm", "mm", 0.1, 0.0, 1.5, 0.0, _src, "slip path length"),)
    differentiable = ("smear_mm",)
    steps = 7

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        return [("rand", (n,))]

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        n = x.shape[0]
        theta = torch.rand(n, generator=generator) * 2 * math.pi
        if not ctx.stochastic:
            theta = theta * 0
        # step k samples x bilinearly at p + t_k (cos, sin), clamped to the border: per image a
        # separable 2-tap filter, so the mean over the steps is one small per-image kernel
        # applied to the replicate-padded map (what grid_sample's border clamp does)
        dx, dy = ctx.mm_per_px(x)
        t = as_tensor(p["smear_mm"]) * torch.linspace(0, 1, self.steps)[:, None]  # (K, 1)
        wx, lo_x = _bilinear_taps(t * torch.cos(theta) / dx)
        wy, lo_y = _bilinear_taps(t * torch.sin(theta) / dy)
        kernel = torch.einsum("kna,knb->nab", wy, wx) / self.steps  # (N, taps_y, taps_x)
        return per_sub_batch(lambda a, k: _per_image_filter(a, k, lo_y, lo_x), x, kernel)


def _bilinear_taps(shift_px: torch.Tensor) -> tuple[torch.Tensor, int]:
    """Weights (K, N, T) of linear interpolation at offsets ``lo .. lo + T - 1`` px.

    Sampling at p + s takes (1 - f) of pixel floor(s) and f of floor(s) + 1, f = s - floor(s);
    differentiable in ``shift_px`` through f.
    """
    base = torch.floor(shift_px.detach())
    frac = shift_px - base
    lo = int(base.min())
    offsets = torch.arange(lo, int(base.max()) + 2, dtype=torch.float32)
    at = (offsets == base[..., None]).float()
    after = (offsets == base[..., None] + 1).float()
    return (1 - frac)[..., None] * at + frac[..., None] * after, lo


def _per_image_filter(x: torch.Tensor, kernel: torch.Tensor, lo_y: int, lo_x: int) -> torch.Tensor:
    """out[n, :, i, j] = sum_ab kernel[n, a, b] x[n, :, i + lo_y + a, j + lo_x + b], clamped.

    One depthwise ``conv2d`` (a group per image and channel) on the replicate-padded map.
    """
    n, c, h, w = x.shape
    ty, tx = kernel.shape[1:]
    top, left = max(0, -lo_y), max(0, -lo_x)
    pad = (left, max(0, lo_x + tx - 1), top, max(0, lo_y + ty - 1))
    xp = F.pad(x, pad, mode="replicate").reshape(1, n * c, h + pad[2] + pad[3], w + sum(pad[:2]))
    weight = kernel.repeat_interleave(c, 0)[:, None]
    y = F.conv2d(xp, weight.to(x), groups=n * c)
    y = y.reshape(n, c, y.shape[-2], y.shape[-1])
    i, j = lo_y + top, lo_x + left
    return y[..., i : i + h, j : j + w]
