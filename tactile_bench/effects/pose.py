"""Effects acting on the pose: the real contact is not the commanded one."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import torch

from tactile_bench.effects.base import Draw, Effect, EffectContext, Param, ParamValue, as_tensor
from tactile_bench.effects.draws import randn


def _with(poses: Any, **changes: torch.Tensor) -> Any:
    """A copy of a Poses-like dataclass with some fields replaced (keeps autograd history)."""
    values = {f.name: getattr(poses, f.name) for f in fields(poses)}
    values.update(changes)
    return type(poses)(**values)


class PoseError(Effect):
    name = "pose_error"
    acts_on = "pose"
    stochastic = True
    description = (
        "The object is not where the robot was told to put it. Fixturing and hand-eye "
        "calibration leave a constant offset of the block in the gel plane and about its "
        "normal; backlash and compliance add a random part per contact. The paper names this "
        "misalignment between the TACTO depth and the real image as its main residual."
    )
    _src = (
        "estimate: fixturing and hand-eye calibration leave a few tenths of a mm and a degree of "
        "yaw (not measured here); Higuera et al. 2023 sec. V name this depth-image misalignment "
        "their main residual"
    )
    params = (
        Param("offset_x_mm", "mm", 0.25, -2.0, 2.0, 0.0, _src, "constant offset along x"),
        Param("offset_y_mm", "mm", -0.15, -2.0, 2.0, 0.0, _src, "constant offset along y"),
        Param("jitter_mm", "mm", 0.15, 0.0, 1.0, 0.0, _src, "per-contact std in x and y"),
        Param("yaw_offset_deg", "deg", 1.0, -10.0, 10.0, 0.0, _src, "constant yaw offset"),
        Param("yaw_jitter_deg", "deg", 0.5, 0.0, 5.0, 0.0, _src, "per-contact yaw std"),
    )
    differentiable = tuple(p.name for p in params)

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        return [("randn", (n,))] * 3

    def _apply(
        self,
        x: Any,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Any:
        n = len(x.labels)
        zx, zy, zt = (randn((n,), generator) for _ in range(3))  # as in ``draws``
        if not ctx.stochastic:
            zx, zy, zt = zx * 0, zy * 0, zt * 0
        dx = as_tensor(p["offset_x_mm"]) + as_tensor(p["jitter_mm"]) * zx
        dy = as_tensor(p["offset_y_mm"]) + as_tensor(p["jitter_mm"]) * zy
        dt = as_tensor(p["yaw_offset_deg"]) + as_tensor(p["yaw_jitter_deg"]) * zt
        return _with(x, x_mm=x.x_mm + dx, y_mm=x.y_mm + dy, yaw_deg=x.yaw_deg + dt)


class PressDepthError(Effect):
    name = "press_error"
    acts_on = "pose"
    stochastic = True
    description = (
        "Force control, not position control, sets how far a real object sinks into the gel: "
        "the gel's nonlinear stiffness and the arm's compliance make the real penetration a "
        "scaled and offset version of the commanded depth, with scatter from contact to "
        "contact. The simulator takes the commanded depth literally."
    )
    _src = (
        "estimate: force control, not position, sets the penetration; ~10-20% depth scatter of "
        "force-controlled presses on a 4.6 mm silicone gel (Lambeta et al. 2020, DIGIT)"
    )
    params = (
        Param("depth_scale", "1", 0.85, 0.5, 1.5, 1.0, _src, "real / commanded depth"),
        Param("depth_offset_mm", "mm", -0.03, -0.5, 0.5, 0.0, _src, "constant depth offset"),
        Param("depth_jitter_mm", "mm", 0.05, 0.0, 0.3, 0.0, _src, "per-contact depth std"),
    )
    differentiable = tuple(p.name for p in params)

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        return [("randn", (n,))]

    def _apply(
        self,
        x: Any,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Any:
        z = randn((len(x.labels),), generator)
        if not ctx.stochastic:
            z = z * 0
        press = (
            x.press_mm * as_tensor(p["depth_scale"])
            + as_tensor(p["depth_offset_mm"])
            + as_tensor(p["depth_jitter_mm"]) * z
        )
        return _with(x, press_mm=press.clamp(min=0.0))
