"""The ``calibrated`` translator: the diagnosis's fitted effects as a simulator.

"Real" pairs here are the plain simulator's noise-free images with a planted effect (a blur,
camera noise), so what the fit should find is known. Candidates are restricted to keep each
fit to a few seconds.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from tactile_bench.diagnose import calibrated
from tactile_bench.diagnose.calibrated import CalibratedTranslator, area_strata
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.effects.kernels import gaussian_blur
from tactile_bench.errors import TactileBenchError
from tactile_bench.metrics import estimate_pixel_noise
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.testing import TranslatorContract
from tactile_bench.translators import create_translator, foreground_to_image, image_to_foreground
from tactile_bench.translators.registry import load_checkpoint

SIZE = 32
FAST = {"candidates": ["defocus_blur", "led_diffusivity"]}
QUIET = {"enable_progress_bar": False}


class TestCalibratedContract(TranslatorContract):
    name = "calibrated"
    tiny_config = {"candidates": ["defocus_blur"]}


def domes(n: int, seed: int, size: int = SIZE) -> torch.Tensor:
    """(n, 1, S, S) depth, mm: one dome of random place and radius per contact."""
    gen = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    centre = (torch.rand(n, 2, generator=gen) - 0.5) * 1.2
    radius = (0.15 + 0.2 * torch.rand(n, generator=gen))[:, None, None]
    r2 = (xs - centre[:, 0, None, None]) ** 2 + (ys - centre[:, 1, None, None]) ** 2
    return (0.96 * (1 - r2 / radius**2)).clamp(min=0).unsqueeze(1)


def blurred_real(depth: torch.Tensor, sigma_px: float = 1.5) -> torch.Tensor:
    """The "real" images: noise-free sim whose contact change is blurred (a defocus)."""
    background = sim_background(depth.shape[-1])
    change = SimOptics().render(depth, background, None) - background
    s = torch.tensor(sigma_px)
    return background + gaussian_blur(change, s, s)


@pytest.fixture(scope="module")
def fitted_blur(tmp_path_factory: pytest.TempPathFactory) -> CalibratedTranslator:
    depth = domes(32, seed=0)
    background = sim_background(SIZE)
    translator = create_translator("calibrated", FAST)
    out = tmp_path_factory.mktemp("fit")
    translator.fit_pairs(depth, image_to_foreground(blurred_real(depth), background), out, QUIET)
    return translator


def test_fit_finds_the_planted_blur_and_gets_closer_to_real(fitted_blur) -> None:
    selection = fitted_blur.fit_diagnostics()
    assert list(selection["effects"]) == ["defocus_blur"]
    assert selection["unexplained"] < 0.1 and selection["fit_seconds"] > 0
    depth = domes(16, seed=1)  # contacts the fit never saw
    real, background = blurred_real(depth), sim_background(SIZE)
    gen = torch.Generator
    calibrated = fitted_blur.translate(depth, background, gen().manual_seed(0))
    sim = create_translator("sim").translate(depth, background, gen().manual_seed(0))
    noise_free_sim = SimOptics().render(depth, background, None)
    mse = {k: float((v - real).square().mean()) for k, v in [("cal", calibrated), ("sim", sim)]}
    assert mse["cal"] < 0.1 * mse["sim"]
    assert mse["cal"] < 0.1 * float((noise_free_sim - real).square().mean())


def test_fit_writes_the_diagnosis_result(fitted_blur, tmp_path: Path) -> None:
    depth = domes(12, seed=2)
    translator = create_translator("calibrated", {"candidates": ["defocus_blur"]})
    fg = image_to_foreground(blurred_real(depth), sim_background(SIZE))
    assert translator.fit_pairs(depth, fg, tmp_path, QUIET) is None  # nothing trained
    written = json.loads((tmp_path / "calibration.json").read_text())
    assert written["effects"] == translator.fit_diagnostics()["effects"]
    assert written["which"]["candidates"] == ["defocus_blur"]


def _blur_pairs(n: int = 32, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    depth = domes(n, seed=seed)
    return depth, image_to_foreground(blurred_real(depth), sim_background(SIZE))


@pytest.fixture(scope="module")
def fitted_on_cpu(tmp_path_factory: pytest.TempPathFactory) -> CalibratedTranslator:
    translator = create_translator("calibrated", FAST)
    out = tmp_path_factory.mktemp("fit_cpu")
    translator.fit_pairs(*_blur_pairs(), out, {**QUIET, "accelerator": "cpu"})
    return translator


def test_fit_on_every_device_finds_what_the_cpu_finds(
    device: torch.device, fitted_on_cpu: CalibratedTranslator, tmp_path: Path
) -> None:
    """The search runs where ``accelerator`` points; its state stays with the module (the
    CPU here), and it translates on any device."""
    translator = create_translator("calibrated", FAST)
    translator.fit_pairs(*_blur_pairs(), tmp_path, {**QUIET, "accelerator": device.type})
    want, got = fitted_on_cpu.fit_diagnostics(), translator.fit_diagnostics()
    assert list(got["effects"]) == list(want["effects"]) == ["defocus_blur"]
    for name, params in want["effects"].items():
        assert got["effects"][name] == pytest.approx(params, rel=1e-2, abs=1e-3)
    assert all(b.device.type == "cpu" for b in translator.buffers())
    depth, background = domes(6, seed=7), sim_background(SIZE)
    expected = fitted_on_cpu.translate(depth, background, torch.Generator().manual_seed(2))
    images = translator.to(device).translate(
        depth.to(device), background.to(device), torch.Generator().manual_seed(2)
    )
    assert images.device.type == device.type
    torch.testing.assert_close(images.cpu(), expected, atol=0.5, rtol=1e-2)


def test_fit_moves_the_pairs_to_the_trainer_settings_device(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The device comes from the trainer's ``accelerator`` (``hardware.compute_device``), and
    the diagnosis gets every tensor there: here ``meta``, which no CPU-made tensor joins."""
    asked: list[object] = []
    seen: dict[str, torch.device] = {}

    class Diagnosed(Exception):
        pass

    def device_for(accelerator: object) -> torch.device:
        asked.append(accelerator)
        return torch.device("meta")

    def diagnose(data: DiagnosisPairs, *args: object, **kwargs: object) -> None:
        seen.update({k: getattr(data, k).device for k in ("depth", "sim", "real", "background")})
        raise Diagnosed

    monkeypatch.setattr(calibrated, "compute_device", device_for)
    monkeypatch.setattr(calibrated, "explain_gap", diagnose)
    translator = create_translator("calibrated", FAST)
    with pytest.raises(Diagnosed):
        translator.fit_pairs(*_blur_pairs(8), tmp_path, {**QUIET, "accelerator": "gpu"})
    assert asked == ["gpu"]
    assert set(seen.values()) == {torch.device("meta")} and len(seen) == 4


def test_noise_is_topped_up_to_the_real_level(tmp_path: Path) -> None:
    depth = domes(32, seed=3)
    background = sim_background(SIZE)
    real = SimOptics().render(depth, background, torch.Generator().manual_seed(9)).clamp(0, 255)
    # SimOptics draws std 7 noise: the "real" camera is that noisy, the model's sim is not
    translator = create_translator("calibrated", {"candidates": ["vignetting"]})
    translator.fit_pairs(depth, image_to_foreground(real, background), tmp_path, QUIET)
    added = torch.tensor(translator.fit_diagnostics()["noise_added"])
    assert torch.allclose(added, torch.full((3,), 7.0), atol=0.7)
    out = translator.translate_foreground(domes(16, seed=4), torch.Generator().manual_seed(0))
    measured = 255 * estimate_pixel_noise(out)
    assert torch.allclose(measured, torch.full((3,), 7.0), atol=0.7)


def test_save_load_gives_identical_images(fitted_blur, tmp_path: Path) -> None:
    path = fitted_blur.save(tmp_path / "translator.pt")
    loaded = load_checkpoint(path)
    assert isinstance(loaded, CalibratedTranslator)
    assert loaded.fit_diagnostics() == fitted_blur.fit_diagnostics()
    depth, background = domes(5, seed=5), torch.full((3, SIZE, SIZE), 100.0)
    a = fitted_blur.translate(depth, background, torch.Generator().manual_seed(3))
    b = loaded.translate(depth, background, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    assert not torch.equal(a, loaded.translate(depth, background, torch.Generator()))


def test_chunks_do_not_change_the_images(fitted_blur) -> None:
    depth = domes(7, seed=6)
    backgrounds = torch.linspace(60.0, 180.0, 7).view(7, 1, 1, 1).expand(7, 3, SIZE, SIZE)
    chunked = CalibratedTranslator({**FAST, "chunk": 3})
    chunked.load_state_dict(fitted_blur.state_dict())
    fg = fitted_blur.translate_foreground(depth, torch.Generator().manual_seed(1))
    assert torch.equal(fg, chunked.translate_foreground(depth, torch.Generator().manual_seed(1)))
    images = chunked.translate(depth, backgrounds, torch.Generator().manual_seed(1))
    assert torch.equal(images, foreground_to_image(fg, backgrounds))  # each on its own frame


def test_unfitted_is_the_plain_simulator() -> None:
    depth, background = domes(4, seed=7), torch.full((3, SIZE, SIZE), 120.0)
    calibrated, sim = create_translator("calibrated"), create_translator("sim")
    assert calibrated.fit_diagnostics() == {}

    def gen() -> torch.Generator:
        return torch.Generator().manual_seed(2)

    images = [t.translate(depth, background, gen()) for t in (calibrated, sim)]
    foregrounds = [t.translate_foreground(depth, gen()) for t in (calibrated, sim)]
    assert torch.equal(*images) and torch.equal(*foregrounds)


def test_other_image_size_than_fitted_is_one_line(fitted_blur) -> None:
    with pytest.raises(TactileBenchError, match="fitted on 32 x 32 depths, got 64 x 64"):
        fitted_blur.translate_foreground(domes(2, seed=8, size=64))


@pytest.mark.parametrize(
    ("config", "key"),
    [
        ({"candidates": ["no_such_effect"]}, "candidates"),
        ({"candidates": []}, "candidates"),
        ({"candidates": ["unit_background"]}, "candidates"),  # not a diagnosis candidate
        ({"fit_fraction": 1.0}, "fit_fraction"),
        ({"strata": 0}, "strata"),
        ({"chunk": 0}, "chunk"),
        ({"colour": 1}, "colour"),
    ],
)
def test_bad_config_is_one_line_naming_the_key(config: dict, key: str) -> None:
    with pytest.raises(TactileBenchError) as info:
        create_translator("calibrated", config)
    message = str(info.value)
    assert "\n" not in message and f"config key {key!r}" in message


@pytest.mark.parametrize(
    ("depth", "foreground", "why"),
    [
        (torch.zeros(3, 1, 8, 8), torch.full((3, 3, 8, 8), 0.5), "at least 4 pairs, got 3"),
        (torch.zeros(6, 1, 8, 8), torch.full((5, 3, 8, 8), 0.5), "does not pair with"),
        (torch.zeros(6, 1, 8, 8), torch.full((6, 3, 4, 4), 0.5), "does not pair with"),
        (torch.zeros(6, 8, 8), torch.full((6, 3, 8, 8), 0.5), "must be"),
    ],
)
def test_unfit_pairs_are_one_line(depth, foreground, why: str, tmp_path: Path) -> None:
    translator = create_translator("calibrated", {"candidates": ["defocus_blur"]})
    with pytest.raises(TactileBenchError, match=why) as info:
        translator.fit_pairs(depth, foreground, tmp_path, QUIET)
    assert "\n" not in str(info.value) and not translator.fitted


def test_a_corrupt_record_is_a_load_error(fitted_blur, tmp_path: Path) -> None:
    path = fitted_blur.save(tmp_path / "translator.pt")
    payload = torch.load(path, weights_only=True)
    payload["state_dict"]["record"] = torch.tensor(
        list(b'{"effects": {"x": {}}}'), dtype=torch.uint8
    )
    torch.save(payload, path)
    with pytest.raises(TactileBenchError, match="unreadable calibration record") as info:
        CalibratedTranslator.load(path)
    assert "\n" not in str(info.value)


def test_area_strata_are_equal_count_bins_in_area_order() -> None:
    depth = torch.zeros(8, 1, 4, 4)
    for i, area in enumerate([5, 1, 7, 3, 2, 8, 6, 4]):
        depth[i].view(-1)[:area] = 0.5
    labels = area_strata(depth, 4)
    assert labels == ["area2", "area0", "area3", "area1", "area0", "area3", "area2", "area1"]
