"""The candidate simulator: a ``PairScene`` with candidate effects added, in catalogue order.

Pose candidates move the scene; geometry candidates change the height, whose colour change
is re-rendered *linearly* with the user's sim optics (``delta + S(h') - S(h)``); the sim's own
no-contact frame is taken through the optics and the linear camera effects with and without
the contact, and only the difference is added to the measured frame; the nonlinear camera
steps then act on that composite where the real ones did (``CameraCandidate.on_composite``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import replace
from typing import TypeVar

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.breakdown import RENDER, RESPONSE_LOOKUP
from tactile_bench.diagnose.candidates import (
    CANDIDATES,
    CameraCandidate,
    Candidate,
    Composite,
    GeometryCandidate,
    OpticsCandidate,
    Params,
    PoseCandidate,
    get_candidate,
)
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.scene import PairScene, fit_reference, make_scene
from tactile_bench.effects import EFFECT_ORDER, EffectContext
from tactile_bench.effects.optics import new_scene
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.response_fit import fit_response, response_design
from tactile_bench.sensor.timing import timed_span

Effects = Mapping[str, Params]
_C = TypeVar("_C", bound=Candidate)


def of_kind(effects: Effects, kind: type[_C]) -> list[tuple[_C, Params]]:
    """The candidates of ``effects`` of one kind with their parameters, in catalogue order."""
    out = []
    for name in EFFECT_ORDER:
        cand = CANDIDATES.get(name)
        if name in effects and isinstance(cand, kind):
            out.append((cand, effects[name]))
    return out


def deterministic_geometry(effects: Effects) -> dict[str, dict[str, float]]:
    """The geometry effects of ``effects`` that draw nothing: what the response lookup is
    refitted under, and what can be baked into a scene's depth."""
    return {
        cand.name: {k: float(v) for k, v in p.items()}
        for cand, p in of_kind(effects, GeometryCandidate)
        if not cand.stochastic and not cand.latent_grid
    }


def lookup_for(scene: PairScene, geometry: Effects) -> torch.Tensor:
    """The response lookup (F, 3, 6) fitted on the fit split under ``geometry``: cached."""
    ref = scene.reference
    if ref is None:
        raise TactileBenchError(
            "optical_response: no fitted lookup (the fit split's pairs were not given)"
        )
    key = json.dumps(
        {n: {k: float(v) for k, v in sorted(p.items())} for n, p in sorted(geometry.items())}
    )
    if key not in ref.lookups:
        height = ref.depth
        if geometry:
            flat = replace(scene.flat(), depth=ref.depth, delta=torch.zeros_like(ref.real_change))
            height = _geometry_height(flat, geometry, None, scene.context(False))
        with torch.no_grad(), timed_span(RESPONSE_LOOKUP):
            try:
                table = fit_response(height, ref.real_change, scene.gel_mm)
                table = torch.as_tensor(table, device=height.device)
            except ValueError:  # no contact in the fit split: the lookup predicts no change
                n_cols = response_design(height[:1, :, :2, :2], scene.gel_mm).shape[-1]
                table = height.new_zeros(n_cols // 6, 3, 6)
        ref.lookups[key] = table.float()
    return ref.lookups[key]


def bake_fixed(scene: PairScene, effects: Effects) -> PairScene:
    """``scene`` with (deterministic) pose and geometry ``effects`` applied once: a new depth
    and colour change, so the effects acting after them are fitted without re-rendering
    them every step."""
    for cand, p in of_kind(effects, PoseCandidate):
        scene = cand.apply(scene, p)
    height, delta = _geometry(scene, effects, None, scene.context())
    baked = {**scene.baked, **deterministic_geometry(effects)}
    return replace(scene.with_contact(height, delta), baked=baked)


def _geometry_height(
    scene: PairScene, effects: Effects, generator: torch.Generator | None, ctx: EffectContext
) -> torch.Tensor:
    """The height after the geometry effects among ``effects``, at the image size."""
    chosen = of_kind(effects, GeometryCandidate)
    if not chosen:
        return scene.depth
    factor = max(cand.oversample for cand, _ in chosen)
    height = scene.depth_at(factor)
    for cand, p in chosen:
        height = cand.apply(height, p, generator, ctx, scene)
    height = height.clamp(min=0.0)
    return F.avg_pool2d(height, factor) if factor > 1 else height


def _geometry(
    scene: PairScene, effects: Effects, generator: torch.Generator | None, ctx: EffectContext
) -> tuple[torch.Tensor, torch.Tensor]:
    """(height, colour change) after the geometry effects, the change re-rendered linearly."""
    chosen = of_kind(effects, GeometryCandidate)
    if not chosen:
        return scene.depth, scene.delta
    factor = max(cand.oversample for cand, _ in chosen)
    height = _geometry_height(scene, effects, generator, ctx)
    return height, scene.delta + scene.sim_change(height) - scene.shading(factor)


def _through_sensor(
    scene: PairScene,
    effects: Effects,
    height: torch.Tensor,
    delta: torch.Tensor | None,
    ctx: EffectContext,
) -> torch.Tensor:
    """The sim's own frame with this contact through the optics and the camera effects that
    are linear in the light, in catalogue order: deterministic, no draws."""
    light = new_scene(height, scene.sim_frame, delta)
    for cand, p in of_kind(effects, OpticsCandidate):
        light = cand.apply(light, p, ctx, scene)
    image = light.composite()
    for cand, p in of_kind(effects, CameraCandidate):
        image = cand.through_sensor(image, p, ctx)
    return image


def render(
    scene: PairScene,
    effects: Effects,
    generator: torch.Generator | None = None,
    stochastic: bool = True,
) -> torch.Tensor:
    """Sim images (N, 3, S, S), 0..255, of ``scene`` with ``effects`` added (module docstring)."""
    with timed_span(RENDER):
        for name in effects:
            get_candidate(name).check(effects[name])
        ctx = scene.context(stochastic)
        if "optical_response" in effects:
            geometry = {**scene.baked, **deterministic_geometry(effects)}
            scene = replace(scene, lookup=lookup_for(scene, geometry))
        for cand, p in of_kind(effects, PoseCandidate):
            scene = cand.apply(scene, p)
        height, delta = _geometry(scene, effects, generator, ctx)
        contact = _through_sensor(scene, effects, height, delta, ctx)
        if contact.shape[0] != len(scene):
            contact = contact.expand(len(scene), -1, -1, -1)
        no_contact = scene.depth.new_zeros(1, 1, scene.size, scene.size)
        flat = _through_sensor(scene, effects, no_contact, None, ctx)
        measured = scene.background
        frames = Composite(measured + (contact - flat), flat, measured)
        for cand, p in of_kind(effects, CameraCandidate):
            frames = cand.on_composite(frames, p, generator, ctx)
        return frames.image.clamp(0.0, 255.0)


def render_background(scene: PairScene, effects: Effects) -> torch.Tensor:
    """The candidate simulator's no-contact frame (3, S, S): zero depth, no per-frame noise."""
    return render(scene.flat(), effects, None, stochastic=False)[0]


def apply_effects(
    data: DiagnosisPairs,
    effects: Effects,
    idx: torch.Tensor | None = None,
    seed: int = 0,
    fit_idx: torch.Tensor | None = None,
) -> torch.Tensor:
    """Sim images (N, 3, S, S), 0..255, of the pairs at ``idx`` with ``effects`` added
    (parameters as ``EffectFit.params``; the rest neutral); seeded for stochastic effects.
    ``fit_idx``: the fit split, which ``optical_response``'s lookup is fitted on."""
    reference = None if fit_idx is None else fit_reference(data, fit_idx)
    scene = make_scene(data, idx, reference)
    with torch.no_grad():
        return render(scene, effects, torch.Generator().manual_seed(seed))
