"""Image metrics in the paper's units and the weight-free distribution distance."""

from __future__ import annotations

import pytest
import torch
from torchmetrics.image.kid import poly_mmd

from tactile_bench.metrics import fit_encoder, kid, mmd2_unbiased, ssim_mse


def test_identical_images_score_perfectly() -> None:
    images = torch.randint(0, 256, (4, 3, 32, 32), generator=torch.Generator().manual_seed(0))
    scores = ssim_mse(images.to(torch.uint8), images.to(torch.uint8))
    assert scores["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert scores["mse"] == 0.0


def test_mse_is_on_0_255_scale() -> None:
    a = torch.full((1, 3, 8, 16), 100.0)
    b = a.clone()
    b[:, :, :, :8] += 6.0  # half the pixels off by 6 -> 36 / 2
    assert ssim_mse(b, a)["mse"] == pytest.approx(18.0)


def test_ssim_falls_with_noise_and_rejects_shape_mismatch() -> None:
    gen = torch.Generator().manual_seed(0)
    base = torch.linspace(60, 200, 32).expand(2, 3, 32, 32).clone()  # smooth, like gel images
    noisy = (base + 20 * torch.randn(base.shape, generator=gen)).clamp(0, 255)
    assert ssim_mse(noisy, base)["ssim"] < 0.95
    with pytest.raises(ValueError, match="shape mismatch"):
        ssim_mse(base, base[:1])


def test_mmd_matches_torchmetrics_and_separates_distributions() -> None:
    gen = torch.Generator().manual_seed(0)
    a, b = torch.randn(200, 16, generator=gen), torch.randn(200, 16, generator=gen)
    torch.testing.assert_close(mmd2_unbiased(a, b), poly_mmd(a, b).float(), rtol=1e-4, atol=1e-5)
    same, _ = kid(a, b, subsets=20, subset_size=100)
    shifted, _ = kid(a, b + 0.5, subsets=20, subset_size=100)
    assert abs(same) < 0.01
    assert shifted > 10 * max(abs(same), 1e-3)


def test_mmd_accepts_unequal_sizes() -> None:
    gen = torch.Generator().manual_seed(1)
    a, b = torch.randn(50, 8, generator=gen), torch.randn(80, 8, generator=gen) + 1.0
    assert mmd2_unbiased(a, b) > 0.1


def _domes(n: int, seed: int, radius: float) -> torch.Tensor:
    """Images of a bright blob on grey, blob radius as the distribution's parameter."""
    gen = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, 32), torch.linspace(-1, 1, 32), indexing="ij")
    centres = torch.rand(n, 2, generator=gen) - 0.5
    r2 = (xs - centres[:, :1, None]) ** 2 + (ys - centres[:, 1:, None]) ** 2
    blob = torch.exp(-r2 / radius**2).unsqueeze(1)
    return 120 + 80 * blob * torch.tensor([1.0, 0.6, 0.3]).view(1, 3, 1, 1)


def test_encoder_is_seeded_and_its_kid_sees_a_shift() -> None:
    real = _domes(128, seed=0, radius=0.3)
    encoder = fit_encoder(real, steps=40, batch_size=32, seed=0)
    again = fit_encoder(real, steps=40, batch_size=32, seed=0)
    torch.testing.assert_close(encoder.features(real[:4]), again.features(real[:4]))
    features = encoder.features(real)
    assert features.shape == (128, encoder.feature_dim)
    same = encoder.features(_domes(128, seed=1, radius=0.3))
    other = encoder.features(_domes(128, seed=2, radius=0.6))
    kid_same, _ = kid(features, same, subsets=10, subset_size=64)
    kid_other, _ = kid(features, other, subsets=10, subset_size=64)
    assert kid_other > 5 * max(kid_same, 1e-4)


def test_ssim_in_chunks_equals_ssim_of_the_whole_batch() -> None:
    """ssim_mse bounds its memory by chunks; the mean over a ragged last chunk is unchanged."""
    from torchmetrics.functional.image import structural_similarity_index_measure

    from tactile_bench.metrics.image import SSIM_CHUNK

    gen = torch.Generator().manual_seed(1)
    real = 255 * torch.rand(2 * SSIM_CHUNK + 5, 3, 24, 24, generator=gen)
    pred = (real + 30 * torch.randn(real.shape, generator=gen)).clamp(0, 255)
    whole = structural_similarity_index_measure(pred, real, data_range=255.0)
    assert ssim_mse(pred, real)["ssim"] == pytest.approx(float(whole), abs=1e-6)
