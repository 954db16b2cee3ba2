"""Diffusion translator internals: schedule, samplers, spaces, EMA, diffusers-style export."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from tactile_bench import hardware
from tactile_bench.errors import TactileBenchError
from tactile_bench.metrics import estimate_pixel_noise, ssim_mse
from tactile_bench.testing import tiny_pairs
from tactile_bench.translators.base import foreground_to_image
from tactile_bench.translators.diffusion import (
    PRESETS,
    SAMPLERS,
    DiffusionTranslator,
    build_unet,
    make_sampler,
)
from tactile_bench.translators.diffusion.torch_model import count_parameters

TINY = {"preset": "tiny", "image_size": 32, "max_steps": 2, "batch_size": 4, "steps": 3}


def fitted(tmp_path: Path, **overrides: object) -> DiffusionTranslator:
    translator = DiffusionTranslator({**TINY, **overrides})
    depth, foreground = tiny_pairs(n=8, size=32)
    translator.fit_pairs(depth, foreground, tmp_path, {"enable_progress_bar": False})
    return translator


def test_paper_schedule_by_default() -> None:
    scheduler = DiffusionTranslator({"preset": "tiny", "prediction": "epsilon"}).noise_scheduler
    assert scheduler.config.num_train_timesteps == 500
    assert scheduler.config.beta_schedule == "linear"
    assert scheduler.config.prediction_type == "epsilon"
    assert scheduler.betas[0].item() == pytest.approx(1e-4)
    assert scheduler.betas[-1].item() == pytest.approx(0.02)


def test_cpu_preset_size_and_conditioning_channels() -> None:
    unet = build_unet(PRESETS["cpu"])
    assert 0.8e6 < count_parameters(unet) < 1.5e6
    assert unet.config.in_channels == 4 and unet.config.out_channels == 3


@pytest.mark.parametrize("name", sorted(SAMPLERS))
def test_every_sampler_is_seeded_and_shares_the_schedule(tmp_path: Path, name: str) -> None:
    translator = fitted(tmp_path, sampler=name)
    sampler = make_sampler(name, translator.noise_scheduler)
    # diffusers moves a scheduler's tables to the device it last noised on
    torch.testing.assert_close(
        sampler.alphas_cumprod.cpu(), translator.noise_scheduler.alphas_cumprod.cpu()
    )
    depth, _ = tiny_pairs(n=2, size=32, seed=1)
    translator.eval()
    a = translator.translate_foreground(depth, torch.Generator().manual_seed(0))
    b = translator.translate_foreground(depth, torch.Generator().manual_seed(0))
    c = translator.translate_foreground(depth, torch.Generator().manual_seed(1))
    assert a.shape == (2, 3, 32, 32) and torch.isfinite(a).all()
    torch.testing.assert_close(a, b)
    assert not torch.equal(a, c)


def test_full_ddpm_chain_visits_every_timestep() -> None:
    config = {**TINY, "train_timesteps": 10, "sampler": "ddpm", "steps": 10}
    translator = DiffusionTranslator(config)
    sampler = make_sampler("ddpm", translator.noise_scheduler)
    sampler.set_timesteps(10)
    assert sampler.timesteps.tolist() == list(range(9, -1, -1))
    depth, _ = tiny_pairs(n=2, size=32)
    assert translator.translate_foreground(depth).shape == (2, 3, 32, 32)


def test_unknown_preset_or_sampler_names_the_key() -> None:
    with pytest.raises(TactileBenchError, match="'preset'"):
        DiffusionTranslator({"preset": "huge"})
    with pytest.raises(TactileBenchError, match="'sampler'"):
        DiffusionTranslator({"sampler": "euler"})
    with pytest.raises(TactileBenchError, match="'stepz'"):
        DiffusionTranslator({"stepz": 3})


def test_foreground_space_round_trip() -> None:
    translator = DiffusionTranslator(TINY)
    _, foreground = tiny_pairs(n=4, size=32)
    x = translator.to_sample_space(foreground)
    assert x.abs().max() <= translator.noise_scheduler.config.clip_sample_range
    torch.testing.assert_close(translator.to_foreground(x), foreground)


def test_chunked_sampling_matches_shape_and_is_seeded() -> None:
    translator = DiffusionTranslator({**TINY, "sample_batch_size": 2})
    depth, _ = tiny_pairs(n=5, size=32)
    a = translator.translate_foreground(depth, torch.Generator().manual_seed(0))
    b = translator.translate_foreground(depth, torch.Generator().manual_seed(0))
    assert a.shape == (5, 3, 32, 32)
    torch.testing.assert_close(a, b)


def test_ema_tracks_training_and_is_optional(tmp_path: Path) -> None:
    with_ema = fitted(tmp_path / "a", ema=True)
    assert int(with_ema.ema_updates) == TINY["max_steps"]
    trained = torch.cat([p.flatten() for p in with_ema.unet.parameters()])
    averaged = torch.cat([p.flatten() for p in with_ema.ema_unet.parameters()])
    assert not torch.equal(trained, averaged)
    assert not any(p.requires_grad for p in with_ema.ema_unet.parameters())
    without = fitted(tmp_path / "b")
    assert without.ema_unet is None and without.inference_unet is without.unet


def _sampling_dtype(translator: DiffusionTranslator) -> tuple[torch.dtype, torch.Tensor]:
    """The dtype the denoiser computed in while sampling, and the foregrounds sampled."""
    seen: list[torch.dtype] = []
    hook = translator.inference_unet.register_forward_hook(
        lambda module, args, out: seen.append(out.sample.dtype)
    )
    try:
        out = translator.translate_foreground(tiny_pairs(n=2, size=32)[0])
    finally:
        hook.remove()
    assert len(set(seen)) == 1, seen
    return seen[0], out


@pytest.mark.parametrize("precision", ["32-true", "bf16-mixed"])
def test_fp32_and_bf16_both_train(tmp_path: Path, precision: str) -> None:
    # tiny on purpose: on a CPU without native bf16 (AVX2) bf16 runs 50-100x slower
    translator = fitted(tmp_path, precision=precision)
    assert translator.training_precision() == precision
    assert translator.inference_precision() == precision
    dtype, out = _sampling_dtype(translator)
    assert dtype == (torch.bfloat16 if precision == "bf16-mixed" else torch.float32)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("native", [False, True])
def test_auto_precision_follows_the_hardware(monkeypatch: pytest.MonkeyPatch, native: bool) -> None:
    monkeypatch.setattr(hardware, "native_bf16", lambda device="cpu": native)
    translator = DiffusionTranslator(TINY)
    expected = "bf16-mixed" if native else "32-true"
    assert translator.config.precision == "auto"
    assert translator.training_precision() == expected
    assert translator.inference_precision() == expected
    assert _sampling_dtype(translator)[0] == (torch.bfloat16 if native else torch.float32)
    # an explicit trainer precision wins over the config's for the fit
    assert translator.training_precision({"precision": "32-true"}) == "32-true"


def test_precision_is_the_only_precision_key() -> None:
    """``bf16`` (the key before ``precision``) is refused by name, as any unknown key."""
    with pytest.raises(TactileBenchError, match="bf16"):
        DiffusionTranslator({**TINY, "bf16": False})
    with pytest.raises(TactileBenchError, match="'precision'"):
        DiffusionTranslator({**TINY, "precision": "fp16"})


def test_save_pretrained_round_trip(tmp_path: Path) -> None:
    translator = fitted(tmp_path)
    out = translator.save_pretrained(tmp_path / "export")
    assert (out / "unet" / "config.json").is_file()
    assert (out / "scheduler" / "scheduler_config.json").is_file()
    meta = json.loads((out / "tactile_bench.json").read_text())
    assert meta["translator"] == "diffusion" and meta["config"]["preset"] == "tiny"
    loaded = DiffusionTranslator.from_pretrained(out)
    depth, _ = tiny_pairs(n=2, size=32, seed=3)
    background = torch.full((3, 32, 32), 100.0)
    before = translator.translate(depth, background, torch.Generator().manual_seed(4))
    after = loaded.translate(depth, background, torch.Generator().manual_seed(4))
    torch.testing.assert_close(before, after)


def test_from_pretrained_rejects_non_exports(tmp_path: Path) -> None:
    with pytest.raises(TactileBenchError, match="not a saved translator"):
        DiffusionTranslator.from_pretrained(tmp_path)
    (tmp_path / "tactile_bench.json").write_text(json.dumps({"translator": "cgan"}))
    with pytest.raises(TactileBenchError, match="'cgan'"):
        DiffusionTranslator.from_pretrained(tmp_path)


def test_sample_speed_reports_images_per_second() -> None:
    assert DiffusionTranslator({**TINY, "steps": 2}).sample_speed(n=2, size=32) > 0


@pytest.mark.slow
def test_conditioning_is_learned(tmp_path: Path) -> None:
    """A few hundred steps on synthetic domes: samples follow their depth (SSIM vs target)."""
    depth, foreground = tiny_pairs(n=256, size=32)
    translator = DiffusionTranslator(
        {"preset": "cpu", "image_size": 32, "max_steps": 300, "batch_size": 32, "lr": 1e-3}
    )
    translator.fit_pairs(depth, foreground, tmp_path, {"enable_progress_bar": False})
    test_depth, test_fg = tiny_pairs(n=16, size=32, seed=9)
    background = torch.full((3, 32, 32), 120.0)
    image = translator.translate(test_depth, background, torch.Generator().manual_seed(0))
    target = foreground_to_image(test_fg, background)
    shuffled = foreground_to_image(test_fg.roll(1, dims=0), background)
    assert ssim_mse(image, target)["ssim"] > ssim_mse(image, shuffled)["ssim"] + 0.05


@pytest.mark.parametrize("prediction", ["epsilon", "v_prediction"])
def test_other_prediction_targets_train_and_sample(tmp_path: Path, prediction: str) -> None:
    translator = fitted(tmp_path, prediction=prediction)
    assert translator.noise_scheduler.config.prediction_type == prediction
    sampler = make_sampler("dpmsolver++", translator.noise_scheduler)
    assert sampler.config.prediction_type == prediction
    depth, _ = tiny_pairs(n=2, size=32)
    assert torch.isfinite(translator.translate_foreground(depth)).all()


def _contact_frames(n: int = 32, size: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    """(depth, foreground): flat gel with one small contact (radius 5 px) a frame, at random."""
    gen = torch.Generator().manual_seed(0)
    ys, xs = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    centres = torch.randint(8, size - 8, (n, 2), generator=gen)
    r2 = (xs - centres[:, 0, None, None]) ** 2 + (ys - centres[:, 1, None, None]) ** 2
    bump = (1.0 - r2 / 25.0).clamp(min=0).unsqueeze(1)
    return bump, 0.5 + 0.2 * bump * torch.tensor([1.0, 0.6, 0.3]).view(1, 3, 1, 1)


def test_pixel_noise_estimate_recovers_the_noise_not_the_contacts() -> None:
    _, clean = _contact_frames()
    std = torch.tensor([1.0, 2.0, 4.0]) / 255
    gen = torch.Generator().manual_seed(1)
    white = clean + torch.randn(clean.shape, generator=gen) * std.view(1, 3, 1, 1)
    torch.testing.assert_close(estimate_pixel_noise(white), std, rtol=0.1, atol=0.0)
    # noise correlated between neighbours (a 2 x 2 box of white noise) keeps its full std
    coarse = torch.randn(clean.shape[0], 3, 32, 32, generator=gen)
    smooth = torch.nn.functional.interpolate(coarse, scale_factor=2.0, mode="nearest")
    correlated = clean + smooth * std.view(1, 3, 1, 1)
    torch.testing.assert_close(estimate_pixel_noise(correlated), std, rtol=0.1, atol=0.0)
    assert (estimate_pixel_noise(clean) < 0.2 / 255).all()  # contacts alone are not noise
    assert estimate_pixel_noise(clean[:4]) is None  # too few frames for a median


def test_samples_carry_the_noise_of_the_training_images(tmp_path: Path) -> None:
    depth, clean = _contact_frames(n=16, size=32)
    gen = torch.Generator().manual_seed(1)
    noisy = clean + torch.randn(clean.shape, generator=gen) * (3 / 255)
    settings = {**TINY, "batch_size": 16}
    translator = DiffusionTranslator(settings)
    translator.fit_pairs(depth, noisy, tmp_path / "on", {"enable_progress_bar": False})
    expected = torch.full((3,), 3 / 255)
    torch.testing.assert_close(translator.pixel_noise_std, expected, rtol=0.15, atol=0.0)
    noisy_sample = translator.translate_foreground(depth, torch.Generator().manual_seed(2))
    translator.config.observation_noise = False
    clean_sample = translator.translate_foreground(depth, torch.Generator().manual_seed(2))
    added = (noisy_sample - clean_sample)[(clean_sample > 0.05) & (clean_sample < 0.95)]
    assert abs(float(added.std()) - 3 / 255) < 0.5 / 255  # the same chain plus the noise

    off = DiffusionTranslator({**settings, "observation_noise": False})
    off.fit_pairs(depth, noisy, tmp_path / "off", {"enable_progress_bar": False})
    assert not off.pixel_noise_std.any()


def test_checkpoints_without_a_noise_estimate_still_load(tmp_path: Path) -> None:
    translator = fitted(tmp_path)
    state = {k: v for k, v in translator.state_dict().items() if "pixel_noise" not in k}
    fresh = DiffusionTranslator(TINY)
    fresh.load_state_dict(state)
    assert not fresh.pixel_noise_std.any()
