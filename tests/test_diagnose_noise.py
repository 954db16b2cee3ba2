"""The pairs' own frame-to-frame noise: estimated from the data, subtracted as a floor."""

from __future__ import annotations

import pytest
import torch

from tactile_bench.diagnose.noise import contact_free, frame_noise
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.which import WhichResult, explain_gap
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank

SIZE = 32


def _scene(n: int = 30, size: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """Contacts in the middle of a textured no-contact light."""
    gen = torch.Generator().manual_seed(1)
    depth = torch.zeros(n, 1, size, size)
    depth[:, :, 18:30, 16:28] = 0.3
    return depth, 90 + 60 * torch.rand(3, size, size, generator=gen)


def _noisy(light: torch.Tensor, n: int, sigma: float, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return light + sigma * torch.randn((n, *light.shape), generator=gen)


def test_each_sides_noise_and_a_frozen_capture_are_measured() -> None:
    depth, light = _scene()
    real = _noisy(light, 30, 3.0, 2).round()  # 8-bit frames
    noise = frame_noise(depth, _noisy(light, 30, 1.0, 3), real, _noisy(light, 1, 2.0, 4)[0], None)
    torch.testing.assert_close(noise.real.sqrt(), torch.full((3,), 3.0), atol=0.15, rtol=0)
    torch.testing.assert_close(noise.sim.sqrt(), torch.full((3,), 1.0), atol=0.1, rtol=0)
    frozen = noise.measured_background.sqrt()
    torch.testing.assert_close(frozen, torch.full((3,), 2.0), atol=0.2, rtol=0)
    assert noise.sim_background.eq(0).all()  # composited: the measured frame's draw counts


def test_a_change_near_the_contact_is_not_noise() -> None:
    depth, light = _scene()
    real = _noisy(light, 30, 2.0, 2)
    # a shadow that reaches past the depth's contact, stronger in every other frame
    real[::2, :, 14:34, 12:32] -= 40
    noise = frame_noise(depth, real.clone(), real, light, light)
    torch.testing.assert_close(noise.real.sqrt(), torch.full((3,), 2.0), atol=0.1, rtol=0)
    assert not contact_free(depth)[0, 0, 14:34, 12:32].any()


def test_another_units_frame_counts_at_most_one_capture_of_noise() -> None:
    depth, light = _scene()
    real = _noisy(light, 30, 2.0, 2)
    noise = frame_noise(depth, real, real, light + 25, None)
    torch.testing.assert_close(noise.measured_background, noise.real)


@pytest.fixture(scope="module")
def bank():
    return build_bank(("A", "L", "#"), BrailleSpec())


def _explain_noisy(bank, planted: dict, sigma: float, candidates: list[str]) -> WhichResult:
    """The diagnosis of 24 planted pairs with independent noise of ``sigma`` added to the
    sim and the real frames alike (every other pair held out)."""
    data = planted_pairs(bank, planted, 24, 3, SIZE)
    gen = torch.Generator().manual_seed(5)
    data.sim = data.sim + sigma * torch.randn(data.sim.shape, generator=gen)
    data.real = data.real + sigma * torch.randn(data.real.shape, generator=gen)
    idx = torch.arange(24)
    return explain_gap(data, idx[::2], idx[1::2], candidates=candidates, progress=False)


def test_noise_against_noise_is_not_called_unexplained(bank) -> None:
    """Nothing planted, both sides noisy (independent draws): what is left is the floor."""
    result = _explain_noisy(bank, {}, 4.0, ["defocus_blur", "vignetting"])
    assert result.gap_floor > 0.5 * result.gap_before
    assert not result.residual_flagged, result.unexplained
    assert all(abs(s - 4.0) < 0.6 for s in result.noise["real"] + result.noise["sim"])


def test_noise_is_refitted_after_a_blur_smooths_the_sims_own(bank) -> None:
    """A blur under noise in sim and real: the blur candidate smooths the sim's noise too,
    so the noise, which alone removed nothing, must be refitted once the blur is in."""
    planted = {"defocus_blur": {"sigma_mm": 0.5}}
    result = _explain_noisy(bank, planted, 6.0, ["defocus_blur", "camera_noise"])
    alone = next(r for r in result.singles if r.effect == "camera_noise")
    assert alone.shrink <= 0  # the sim is as noisy as the real frames
    assert [r.effect for r in result.ranking] == ["defocus_blur", "camera_noise"]
    assert not result.residual_flagged, result.unexplained


def test_8_bit_frames_measure_the_same_noise_as_float_ones() -> None:
    depth, light = _scene()
    real = _noisy(light, 30, 3.0, 2).round().clamp(0, 255)
    as_float = frame_noise(depth, real, real, light.round(), None)
    as_bytes = frame_noise(depth, real.byte(), real.byte(), light.round().byte(), None)
    torch.testing.assert_close(as_bytes.real, as_float.real)
    torch.testing.assert_close(as_bytes.measured_background, as_float.measured_background)


def test_a_response_that_only_smooths_the_sims_noise_is_set_aside(bank) -> None:
    """Nothing planted, both sides noisy: re-rendering the contact from a fitted response
    replaces the sim's noisy colour change with a smooth one and lowers the gap, but with
    the sim's noise put back it removes nothing, so it is not selected."""
    result = _explain_noisy(bank, {}, 4.0, ["optical_response", "defocus_blur"])
    assert [r.effect for r in result.ranking] == []
    assert "optical_response" in result.set_aside_as_denoising


def test_a_real_response_under_noise_is_still_selected(bank) -> None:
    planted = {"optical_response": {"blend": 1.0}}
    result = _explain_noisy(bank, planted, 4.0, ["optical_response", "defocus_blur"])
    assert [r.effect for r in result.ranking][:1] == ["optical_response"]
    assert result.set_aside_as_denoising == []
