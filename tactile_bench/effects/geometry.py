"""Geometry-stage effects: what happens to the surface between the object and the gel.

They act on the signed height (N, 1, H, W) in mm (positive inside the gel), at the render
resolution, in the order object texture -> elastic spread -> shear smear. Where the elastic
spread has displaced the gel the map holds the gel surface (>= 0); the camera sees its
positive part.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from tactile_bench.effects.base import (
    Effect,
    EffectContext,
    Param,
    ParamValue,
    as_tensor,
    gaussian_blur,
    pixel_grid,
    randn,
    scalar,
    shift_mm,
)


class SurfaceTexture(Effect):
    name = "surface_texture"
    stage = "geometry"
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

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        n, _, h, w = x.shape
        uu, vv = pixel_grid(h, w)
        xs, ys = uu * ctx.width_mm / 2, vv * ctx.height_mm / 2
        phase = torch.rand(n, generator=generator) * 2 * math.pi
        rough = randn((n, 1, h, w), generator)
        if not ctx.stochastic:
            phase, rough = phase * 0, rough * 0
        yaw = ctx.yaw_deg if ctx.yaw_deg is not None else torch.zeros(n)
        ang = torch.deg2rad(as_tensor(p["bead_angle_deg"]).detach() + yaw.detach().float())
        s = xs * torch.cos(ang)[:, None, None] + ys * torch.sin(ang)[:, None, None]
        pitch = scalar(p["bead_pitch_mm"])
        bead = torch.abs(torch.sin(math.pi * s / pitch + phase[:, None, None])) - 2 / math.pi
        out = x + as_tensor(p["bead_amp_mm"]) * bead[:, None]
        # terraces: steps of one layer measured down from the block's top
        layer = scalar(p["layer_mm"])
        depth = x.detach().amax(dim=(2, 3), keepdim=True) - x
        out = out + as_tensor(p["terrace"]) * layer / (2 * math.pi) * torch.sin(
            2 * math.pi * depth / layer
        )
        # micro-roughness: white noise low-passed to the correlation length, unit RMS
        dx, dy = ctx.mm_per_px(x)
        corr = scalar(p["roughness_corr_mm"])
        field = gaussian_blur(rough, torch.tensor(corr / dx), torch.tensor(corr / dy))
        field = field / field.detach().pow(2).mean(dim=(2, 3), keepdim=True).clamp(min=1e-12).sqrt()
        return out + as_tensor(p["roughness_mm"]) * field


class ElasticSpread(Effect):
    name = "elastic_spread"
    stage = "geometry"
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
        pen = x.clamp(min=0.0)
        peak = pen.detach().amax(dim=(2, 3), keepdim=True)
        core = (pen.detach() > scalar(p["contact_scale"]) * peak) & (pen.detach() > 0)
        dx, dy = ctx.mm_per_px(x)
        sigma = as_tensor(p["sigma_mm"])
        z = pen
        level = sigma
        while float(level.detach()) / min(dx, dy) >= 1.0:
            z = gaussian_blur(z, level / dx, level / dy)
            z = torch.where(core, pen, z)
            level = level / 2
        # the gel follows the object where they touch (never passes through it) and sags
        # around it; elsewhere the object stays where it was (identity at sigma = 0)
        return torch.where(z > 0, torch.maximum(z, x), x)


class ShearSmear(Effect):
    name = "shear_smear"
    stage = "geometry"
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
        length = as_tensor(p["smear_mm"])
        acc = torch.zeros_like(x)
        for k in range(self.steps):
            t = length * (k / (self.steps - 1))
            acc = acc + shift_mm(x, t * torch.cos(theta), t * torch.sin(theta), ctx)
        return acc / self.steps
