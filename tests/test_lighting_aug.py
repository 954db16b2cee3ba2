"""The ``lighting_aug`` translator: random lights in the sim optics, or a kornia draw applied to
image and background alike; camera noise measured on real foregrounds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.testing import tiny_pairs
from tactile_bench.translators import create_translator
from tactile_bench.translators.lighting_aug import LightingAugTranslator

SIZE = 32
MODES = ["physical", "image"]
NOMINAL = {  # every range collapsed onto TACTO's lights
    "light_angle_jitter_deg": 0.0,
    "light_radius_mm": (20.0, 20.0),
    "light_distance_mm": (17.0, 17.0),
    "light_intensity": (1.0, 1.0),
    "light_crosstalk": 0.0,
}


def make(**config: object) -> LightingAugTranslator:
    translator = create_translator("lighting_aug", config)
    assert isinstance(translator, LightingAugTranslator)
    return translator


def depths(n: int = 4) -> torch.Tensor:
    return tiny_pairs(n=n, size=SIZE)[0] * 0.3  # domes up to 0.24 mm, braille-like


def corner_dot(n: int = 3) -> torch.Tensor:
    """A small dot in the top-left corner of each image: the rest of the gel is untouched."""
    depth = torch.zeros(n, 1, SIZE, SIZE)
    depth[:, :, 3:7, 3:7] = 0.2
    return depth


def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


@pytest.mark.parametrize("mode", MODES)
def test_same_seed_same_images_other_seed_other_images(mode: str) -> None:
    translator, background = make(mode=mode), sim_background(SIZE)
    a = translator.translate(depths(), background, gen(0))
    torch.testing.assert_close(a, translator.translate(depths(), background, gen(0)))
    assert (a - translator.translate(depths(), background, gen(1))).abs().mean() > 0.5


def test_different_seeds_draw_different_lights() -> None:
    translator = make()
    positions_a, colours_a = translator.draw_lights(5, gen(0))
    positions_b, colours_b = translator.draw_lights(5, gen(1))
    assert (positions_a - positions_b).abs().min() > 0  # every coordinate of every light
    assert (colours_a - colours_b).abs().min() > 0
    # and within the configured ranges: radius 17..23 mm, distance 14..20 mm
    radius = positions_a[..., :2].norm(dim=-1)
    assert radius.min() >= 17.0 and radius.max() <= 23.0
    assert positions_a[..., 2].min() >= 14.0 and positions_a[..., 2].max() <= 20.0


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("noise", [False, True])
def test_a_flat_gel_is_the_background_plus_noise_only(mode: str, noise: bool) -> None:
    """No lighting leaks into the foreground: a flat gel changes nothing but the noise."""
    translator = make(mode=mode, camera_noise=noise)
    flat = torch.zeros(16, 1, SIZE, SIZE)
    foreground = translator.translate_foreground(flat, gen(2))
    if not noise:
        assert torch.equal(foreground, torch.full_like(foreground, 0.5))
        background = torch.rand(3, SIZE, SIZE, generator=gen(3)) * 200 + 20
        assert torch.equal(
            translator.translate(flat, background, gen(2)), background.expand(16, -1, -1, -1)
        )
    else:  # noise only: mean 0.5, SimOptics' std 7 on 0-255
        assert abs(foreground.mean().item() - 0.5) < 0.002
        assert foreground.std().item() * 255 == pytest.approx(7.0, rel=0.05)


def test_image_mode_leaves_untouched_pixels_exactly_alone() -> None:
    """The same kornia draw on image and background: away from the contact they cancel
    (subtracting the unaugmented background, as before, left ~20 levels on every pixel)."""
    translator = make(mode="image", camera_noise=False)
    background = sim_background(SIZE)
    image = translator.translate(corner_dot(8), background, gen(4))
    # beyond the blur's reach of the dot; not exactly 0: ColorJitter's contrast blends with
    # the frame's mean grey, which the dot moves a little (far below one 8-bit step)
    far = (image - background)[:, :, 14:, 14:]
    assert far.abs().amax() < 0.1
    assert (image - background)[:, :, :9, :9].abs().amax() > 1.0  # the dot itself is drawn


def test_physical_contact_change_varies_across_draws() -> None:
    translator, background = make(camera_noise=False), sim_background(SIZE)
    depth = depths(1).expand(6, -1, -1, -1)  # one contact, six lightings
    change = translator.translate(depth, background, gen(5)) - background
    spread = change.std(dim=0).mean() / change.abs().mean()
    assert spread > 0.1
    # per channel: cross-talk and moving lights change the colours, not only the strength
    direction = change.flatten(2) / change.flatten(2).norm(dim=-1, keepdim=True)
    assert (direction[0] * direction[1]).sum(-1).min() < 0.995


def test_nominal_lights_reproduce_the_simulator() -> None:
    translator, background = make(camera_noise=False, **NOMINAL), sim_background(SIZE)
    expected = SimOptics().render(depths(), background, None)
    torch.testing.assert_close(
        translator.translate(depths(), background, gen(6)), expected, atol=1e-3, rtol=0
    )


@pytest.mark.parametrize("touched", ["sparse", "dense"])
def test_lit_shading_with_nominal_lights_is_shade_change(touched: str) -> None:
    optics, gel = SimOptics(), GelSpec(size=SIZE)
    depth = corner_dot(2) if touched == "sparse" else depths(2) + 0.01  # 0.01: all touched
    lights = optics.light_positions().expand(2, 3, 3)
    colours = (torch.eye(3) * optics.intensity).expand(2, 3, 3)
    torch.testing.assert_close(
        optics.shade_change_lit(depth, gel, lights, colours),
        optics.shade_change(depth, gel),
        atol=1e-3,
        rtol=0,
    )


PLANTED = (0.01, 0.015, 0.005)  # per-channel noise std, foreground units (7 / 255 = 0.027)


def noisy_foregrounds(std: tuple[float, float, float], n: int = 32) -> tuple[torch.Tensor, ...]:
    """Real-like pairs: small contacts (~5% of the pixels, as braille) plus planted noise."""
    depth = (tiny_pairs(n=n, size=SIZE, seed=8)[0] - 0.5).clamp(min=0)
    foreground = 0.5 + torch.tensor([0.3, -0.2, 0.1]).view(1, 3, 1, 1) * depth
    noise = torch.randn(foreground.shape, generator=gen(9)) * torch.tensor(std).view(1, 3, 1, 1)
    return depth, foreground + noise


def fitted(tmp_path: Path) -> LightingAugTranslator:
    translator = make()
    assert translator.fit_pairs(*noisy_foregrounds(PLANTED), tmp_path) is None
    return translator


def test_fit_measures_the_planted_noise_and_uses_it(tmp_path: Path) -> None:
    planted = torch.tensor(PLANTED)
    translator = fitted(tmp_path)
    torch.testing.assert_close(translator.pixel_noise_std, planted, rtol=0.1, atol=0)
    flat = translator.translate_foreground(torch.zeros(32, 1, SIZE, SIZE), gen(10))
    measured = (flat - 0.5).transpose(0, 1).flatten(1).std(dim=1)
    torch.testing.assert_close(measured, planted, rtol=0.1, atol=0)


def test_fit_needs_enough_real_frames(tmp_path: Path) -> None:
    depth, foreground = tiny_pairs(n=5, size=SIZE)
    with pytest.raises(TactileBenchError, match="at least 8 real foregrounds, got 5"):
        make().fit_pairs(depth, foreground, tmp_path)


def test_checkpoint_round_trip_keeps_the_fitted_noise(tmp_path: Path) -> None:
    translator = fitted(tmp_path)
    loaded = LightingAugTranslator.load(translator.save(tmp_path / "translator.pt"))
    assert bool(loaded.camera_noise_fitted)
    torch.testing.assert_close(loaded.pixel_noise_std, translator.pixel_noise_std)
    torch.testing.assert_close(loaded.pixel_noise_std, torch.tensor(PLANTED), rtol=0.1, atol=0)
    background = sim_background(SIZE)
    torch.testing.assert_close(
        loaded.translate(depths(), background, gen(11)),
        translator.translate(depths(), background, gen(11)),
    )


def test_a_checkpoint_from_before_the_noise_fit_loads_unfitted(tmp_path: Path) -> None:
    translator = make()
    path = translator.save(tmp_path / "old.pt")
    payload = torch.load(path, weights_only=True)
    payload["state_dict"] = {"augment.RandomGamma_1._param_generator.gamma_factor": torch.ones(2)}
    torch.save(payload, path)
    loaded = LightingAugTranslator.load(path)
    assert not bool(loaded.camera_noise_fitted)
    torch.testing.assert_close(loaded.pixel_noise_std, torch.full((3,), 7.0 / 255))


@pytest.mark.parametrize(
    ("config", "key"),
    [
        ({"mode": "blur"}, "mode"),
        ({"light_radius_mm": (23.0, 17.0)}, "light_radius_mm"),
        ({"light_distance_mm": (0.0, 20.0)}, "light_distance_mm"),
        ({"light_crosstalk": 2.0}, "light_crosstalk"),
        ({"gamma": (1.2, 0.8)}, "gamma"),
        ({"noise_std": 0.02}, "noise_std"),  # gone: the camera noise replaced it
    ],
)
def test_config_errors_are_one_line_naming_the_key(config: dict, key: str) -> None:
    with pytest.raises(TactileBenchError) as info:
        make(**config)
    message = str(info.value)
    assert "\n" not in message and f"config key '{key}" in message


RECIPE = """
name: aug_chain
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 40, n_test: 16, n_classifier: 8}
  - name: fit_aug
    kind: fit_translator
    inputs: {braille: braille}
    config: {translator: lighting_aug, fraction: 0.5, eval_pairs: 0}
  - name: translate_aug
    kind: translate
    inputs: {data: braille, translator: fit_aug}
    config: {sets: [test]}
"""


def test_a_recipe_fits_the_noise_then_translates_with_it(tmp_path: Path) -> None:
    (tmp_path / "chain.yaml").write_text(RECIPE)
    run_dir = tmp_path / "run"
    assert (
        main(["fit", str(tmp_path / "chain.yaml"), "--run-dir", str(run_dir), "--no-progress"]) == 0
    )
    run = json.loads((run_dir / "run.json").read_text())
    dirs = {s["name"]: run_dir / s["directory"] for s in run["stages"]}
    fit = LightingAugTranslator.load(dirs["fit_aug"] / "translator.pt")
    assert bool(fit.camera_noise_fitted)
    assert json.loads((dirs["fit_aug"] / "metrics.json").read_text())["fit_pairs"] == 20
    # the translate stage used that fitted translator: same seed, same images
    test = BrailleSet.load(dirs["braille"] / "test.npz")
    expected = fit.translate(test.depth, test.real_background.float(), gen(0))  # recipe seed
    images = np.load(dirs["translate_aug"] / "test.npz")["images"]
    torch.testing.assert_close(torch.from_numpy(images).float(), expected.round(), atol=0, rtol=0)
