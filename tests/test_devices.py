"""Every kernel computes where its inputs live (issue 39).

Two checks. On ``meta`` tensors (shapes, no values) a tensor made on the CPU inside a kernel
fails at once, so this file catches what a GPU would catch, on a machine without one; steps
that need values (a data-dependent index, a flag read back) cannot run on ``meta`` and are
left to the second check. The ``device`` fixture runs the same kernels on every device this
machine has (the CPU, and CUDA where there is a GPU; ``tests/conftest.py``) against the
CPU's result.
"""

from __future__ import annotations

import pytest
import torch

from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.effects import EFFECTS
from tactile_bench.effects.base import EffectContext, OpticalScene
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.testing import tiny_pairs

META = torch.device("meta")
SIZE = 32
IMAGE_EFFECTS = sorted(n for n, e in EFFECTS.items() if e.acts_on != "pose")


def _effect_input(name: str, device: torch.device, seed: int = 0) -> torch.Tensor | OpticalScene:
    depth, _ = tiny_pairs(n=2, size=SIZE, seed=seed)
    depth = depth.to(device)
    acts_on = EFFECTS[name].acts_on
    if acts_on == "geometry":
        return depth
    if acts_on == "camera":
        return torch.full((2, 3, SIZE, SIZE), 120.0, device=device) + 40 * depth
    background = torch.full((2, 3, SIZE, SIZE), 110.0, device=device)
    return OpticalScene(depth, background, 30 * depth.expand(-1, 3, -1, -1), depth * 0 + 1)


def _apply_effect(name: str, x: torch.Tensor | OpticalScene) -> list[torch.Tensor]:
    effect = EFFECTS[name]
    device = x.delta.device if isinstance(x, OpticalScene) else x.device
    ctx = EffectContext(yaw_deg=torch.zeros(2, device=device))
    out = effect.apply(x, effect.defaults(), torch.Generator().manual_seed(0), ctx)
    if isinstance(out, OpticalScene):
        return [out.height, out.background, out.delta, out.gain]
    return [out]


@pytest.mark.parametrize("name", IMAGE_EFFECTS)
def test_effect_keeps_meta_inputs_on_meta(name: str) -> None:
    outputs = _apply_effect(name, _effect_input(name, META))
    assert all(o.device == META for o in outputs)


@pytest.mark.parametrize("name", IMAGE_EFFECTS)
def test_effect_on_every_device_matches_the_cpu(name: str, device: torch.device) -> None:
    expected = _apply_effect(name, _effect_input(name, torch.device("cpu")))
    outputs = _apply_effect(name, _effect_input(name, device))
    for got, want in zip(outputs, expected, strict=True):
        assert got.device.type == device.type
        torch.testing.assert_close(got.cpu(), want, atol=1e-3, rtol=1e-3)


def test_sim_optics_keeps_meta_inputs_on_meta() -> None:
    depth = torch.zeros(2, 1, SIZE, SIZE, device=META)
    background = torch.zeros(3, SIZE, SIZE, device=META)
    image = SimOptics().render(depth, background, torch.Generator().manual_seed(0))
    assert image.device == META and image.shape == (2, 3, SIZE, SIZE)


def test_sim_optics_on_every_device_matches_the_cpu(device: torch.device) -> None:
    depth, _ = tiny_pairs(n=3, size=SIZE, seed=2)
    background = torch.full((3, SIZE, SIZE), 100.0)
    optics = SimOptics()
    want = optics.render(depth, background, torch.Generator().manual_seed(1))
    got = optics.render(depth.to(device), background.to(device), torch.Generator().manual_seed(1))
    assert got.device.type == device.type
    torch.testing.assert_close(got.cpu(), want, atol=1e-2, rtol=1e-3)


def test_surrogate_keeps_meta_inputs_on_meta() -> None:
    surrogate = SurrogateDigit.from_profile("digit")
    height = torch.zeros(2, 1, 2 * SIZE, 2 * SIZE, device=META)
    image = surrogate.render_surface(height, surrogate.gel(SIZE), torch.Generator().manual_seed(0))
    assert image.device == META and image.shape == (2, 3, SIZE, SIZE)


def test_surrogate_on_every_device_matches_the_cpu(device: torch.device) -> None:
    surrogate = SurrogateDigit.from_profile("digit")
    depth, _ = tiny_pairs(n=2, size=2 * SIZE, seed=3)
    gel = surrogate.gel(SIZE)
    want = surrogate.render_surface(depth, gel, torch.Generator().manual_seed(4))
    got = surrogate.render_surface(depth.to(device), gel, torch.Generator().manual_seed(4))
    assert got.device.type == device.type
    assert (got.cpu() - want).abs().mean() < 0.5


def test_classifier_keeps_meta_inputs_on_meta() -> None:
    model = BrailleClassifier(width=8).to(META)
    logits = model(torch.zeros(4, 3, SIZE, SIZE, device=META))
    assert logits.device == META and logits.shape[0] == 4


def test_classifier_on_every_device_matches_the_cpu(device: torch.device) -> None:
    model = BrailleClassifier(width=8).eval()
    x, _ = tiny_pairs(n=4, size=SIZE, seed=5)
    x = x.expand(-1, 3, -1, -1).contiguous()
    want = model(x)
    got = model.to(device)(x.to(device))
    assert got.device.type == device.type
    torch.testing.assert_close(got.cpu(), want, atol=1e-3, rtol=1e-3)
