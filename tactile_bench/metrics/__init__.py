"""Image metrics as the paper reports them, and a weight-free distribution distance."""

from tactile_bench.metrics.encoder import FeatureEncoder, fit_encoder, kid, mmd2_unbiased
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.metrics.noise import estimate_pixel_noise

__all__ = [
    "FeatureEncoder",
    "estimate_pixel_noise",
    "fit_encoder",
    "kid",
    "mmd2_unbiased",
    "ssim_mse",
]
