"""Distribution distance between image sets without downloaded weights.

FID/KID normally use ImageNet Inception features; nothing here may download weights, so the
features come from the project's own small convolutional autoencoder, trained from scratch
(seeded) on real images. The caller caches the fitted encoder (``state_dict``). The distance
is KID: the unbiased MMD^2 with the cubic polynomial kernel k(x, y) = (x.y / d + 1)^3,
averaged over random subsets (Binkowski et al. 2018), as torchmetrics computes it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class FeatureEncoder(nn.Module):
    """(N, 3, H, W) images -> (N, feature_dim) features, any size (the reconstruction is
    cropped to the input where a side is not divisible by 8).

    Inputs are standardised by per-channel statistics of the training images (buffers), so
    the encoder accepts images in 0..255 or foregrounds around 0.5 alike.
    """

    def __init__(self, width: int = 16, code_channels: int = 32, pool: int = 2) -> None:
        super().__init__()
        self.encoder = nn.Sequential(
            nn.Conv2d(3, width, 3, 2, 1),
            nn.SiLU(),
            nn.Conv2d(width, 2 * width, 3, 2, 1),
            nn.SiLU(),
            nn.Conv2d(2 * width, code_channels, 3, 2, 1),
        )
        self.decoder = nn.Sequential(
            nn.SiLU(),
            nn.ConvTranspose2d(code_channels, 2 * width, 4, 2, 1),
            nn.SiLU(),
            nn.ConvTranspose2d(2 * width, width, 4, 2, 1),
            nn.SiLU(),
            nn.ConvTranspose2d(width, 3, 4, 2, 1),
        )
        self.pool = pool
        self.register_buffer("mean", torch.zeros(1, 3, 1, 1))
        self.register_buffer("std", torch.ones(1, 3, 1, 1))

    @property
    def feature_dim(self) -> int:
        return self.encoder[-1].out_channels * self.pool**2

    def normalise(self, images: torch.Tensor) -> torch.Tensor:
        return (images.float() - self.mean) / self.std

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Reconstruction of the normalised images (the training objective)."""
        h, w = images.shape[-2:]
        return self.decoder(self.encoder(self.normalise(images)))[..., :h, :w]

    @torch.no_grad()
    def features(self, images: torch.Tensor, batch_size: int = 256) -> torch.Tensor:
        """Pooled bottleneck codes: a coarse spatial layout of what the encoder saw, computed
        on the encoder's device and returned on the images'."""
        self.eval()
        device = self.mean.device
        out = [
            F.adaptive_avg_pool2d(self.encoder(self.normalise(part.to(device))), self.pool)
            .flatten(1)
            .to(images.device)
            for part in images.split(batch_size)
        ]
        return torch.cat(out)


def fit_encoder(
    images: torch.Tensor,
    steps: int = 500,
    batch_size: int = 64,
    lr: float = 2e-3,
    seed: int = 0,
    device: torch.device | str = "cpu",
    **kwargs: int,
) -> FeatureEncoder:
    """Train a FeatureEncoder to reconstruct ``images`` (N, 3, S, S) on ``device``; seeded
    (the batches are drawn on the CPU, the same on every device), CPU-fast."""
    gen = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        encoder = FeatureEncoder(**kwargs).to(device)
    images = images.float().to(device)
    encoder.mean.copy_(images.mean(dim=(0, 2, 3), keepdim=True))
    encoder.std.copy_(images.std(dim=(0, 2, 3), keepdim=True).clamp(min=1e-6))
    optimiser = torch.optim.Adam(encoder.parameters(), lr=lr)
    encoder.train()
    for _ in range(steps):
        batch = images[torch.randint(0, len(images), (batch_size,), generator=gen).to(device)]
        loss = F.mse_loss(encoder(batch), encoder.normalise(batch))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return encoder.eval()


def _poly_kernel(a: torch.Tensor, b: torch.Tensor, degree: int, coef: float) -> torch.Tensor:
    return (a @ b.T / a.shape[1] + coef) ** degree


def mmd2_unbiased(
    features_a: torch.Tensor, features_b: torch.Tensor, degree: int = 3, coef: float = 1.0
) -> torch.Tensor:
    """Unbiased MMD^2 with a polynomial kernel; sets may differ in size (each >= 2)."""
    a, b = features_a.double(), features_b.double()
    m, n = len(a), len(b)
    k_aa, k_bb = _poly_kernel(a, a, degree, coef), _poly_kernel(b, b, degree, coef)
    k_ab = _poly_kernel(a, b, degree, coef)
    within_a = (k_aa.sum() - k_aa.diagonal().sum()) / (m * (m - 1))
    within_b = (k_bb.sum() - k_bb.diagonal().sum()) / (n * (n - 1))
    return (within_a + within_b - 2 * k_ab.mean()).float()


def kid(
    features_a: torch.Tensor,
    features_b: torch.Tensor,
    subsets: int = 50,
    subset_size: int = 100,
    seed: int = 0,
) -> tuple[float, float]:
    """KID (mean, std) over random equal-size subsets, as torchmetrics' KernelInceptionDistance."""
    size = min(subset_size, len(features_a), len(features_b))
    gen = torch.Generator().manual_seed(seed)
    values = torch.stack(
        [
            mmd2_unbiased(
                features_a[torch.randperm(len(features_a), generator=gen)[:size]],
                features_b[torch.randperm(len(features_b), generator=gen)[:size]],
            )
            for _ in range(subsets)
        ]
    )
    return float(values.mean()), float(values.std()) if subsets > 1 else 0.0
