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
from tactile_bench.diagnose.candidates import CANDIDATES
from tactile_bench.diagnose.gapfit import (
    FitBudget,
    Target,
    fit_candidate,
    model_gap,
    pair_gap,
    rounding_gap,
)
from tactile_bench.diagnose.noise import frame_noise
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.scene import fit_reference, make_scene
from tactile_bench.diagnose.simulate import render
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.where import analyse_where
from tactile_bench.effects import EFFECTS
from tactile_bench.effects.base import EffectContext, OpticalScene
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank
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


# ----------------------------------------------------------------- the diagnosis's kernels
#: candidates whose render reads a value back (cannot run on ``meta``): the device check
#: below runs them
READS_VALUES = {
    "press_error": "whether the press changes any depth is read back",
    "optical_response": "the lookup's least squares reads its normal matrix back",
    "jpeg_stored": "Pillow codes the frames' bytes",
}
#: each candidate at its search's start, and the codec at the stored frame size (Pillow)
CANDIDATE_CASES = {
    **{name: {name: {s.name: s.start for s in c.searched}} for name, c in CANDIDATES.items()},
    "jpeg_stored": {"jpeg": {"quality": 80.0, "stored_size": 1.0}},
}
FIT_IDX, HELD_IDX = torch.arange(0, 8, 2), torch.arange(1, 8, 2)


@pytest.fixture(scope="module")
def diagnosis_pairs() -> DiagnosisPairs:
    bank = build_bank(("A", "L"), BrailleSpec())
    return planted_pairs(bank, {"vignetting": {"corner_loss": 0.3}}, 8, 3, SIZE)


@pytest.mark.parametrize("case", sorted(set(CANDIDATE_CASES) - set(READS_VALUES)))
def test_candidate_and_gap_keep_meta_inputs_on_meta(
    case: str, diagnosis_pairs: DiagnosisPairs
) -> None:
    data = diagnosis_pairs.to(META)
    image = render(make_scene(data), CANDIDATE_CASES[case], torch.Generator().manual_seed(0))
    gap = pair_gap([image, image], Target.of(data.real))
    assert image.device == META and image.shape == data.sim.shape
    assert gap.device == META and gap.shape == (len(data),)


def _diagnosis_kernels(data: DiagnosisPairs, case: str) -> list[torch.Tensor]:
    """A candidate's render and held-out gap (its per-pair latent searched), with the fit
    split's reference (the response lookup), on ``data``'s device."""
    scene = make_scene(data, HELD_IDX, fit_reference(data, FIT_IDX))
    effects = CANDIDATE_CASES[case]
    image = render(scene, effects, torch.Generator().manual_seed(0))
    return [image, model_gap(scene, Target.of(data.real[HELD_IDX]), effects, seed=1)]


@pytest.mark.parametrize("case", sorted(CANDIDATE_CASES))
def test_candidate_on_every_device_matches_the_cpu(
    case: str, device: torch.device, diagnosis_pairs: DiagnosisPairs
) -> None:
    want = _diagnosis_kernels(diagnosis_pairs, case)
    got = _diagnosis_kernels(diagnosis_pairs.to(device), case)
    for g, w in zip(got, want, strict=True):
        assert g.device.type == device.type
        torch.testing.assert_close(g.cpu(), w, atol=1e-2, rtol=1e-2)


def test_candidate_fit_on_every_device_matches_the_cpu(
    device: torch.device, diagnosis_pairs: DiagnosisPairs
) -> None:
    """The search (sweeps, Adam through the blur) where the pairs live: the same sigma."""
    budget = FitBudget(sweep_pairs=4, adam_pairs=4, adam_steps=4)

    def fitted(data: DiagnosisPairs) -> float:
        scene = make_scene(data, FIT_IDX, fit_reference(data, FIT_IDX))
        target = Target.of(data.real[FIT_IDX])
        return fit_candidate("defocus_blur", scene, target, budget=budget)["sigma_mm"]

    assert fitted(diagnosis_pairs.to(device)) == pytest.approx(fitted(diagnosis_pairs), abs=0.01)


def test_gap_problem_parts_on_every_device_match_the_cpu(
    device: torch.device, diagnosis_pairs: DiagnosisPairs
) -> None:
    """The pairs' own noise, the rounding gap and the error's split (``where``)."""

    def parts(data: DiagnosisPairs) -> list[torch.Tensor]:
        noise = frame_noise(data.depth, data.sim, data.real, data.background, None)
        rounding = torch.tensor(rounding_gap(Target.of(data.real), seed=2))
        mse = torch.tensor(analyse_where(data).summary["mse"])
        return [noise.sim, noise.real, noise.measured_background, rounding, mse]

    want, got = parts(diagnosis_pairs), parts(diagnosis_pairs.to(device))
    assert got[0].device.type == device.type
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g.cpu(), w, atol=1e-3, rtol=1e-3)
