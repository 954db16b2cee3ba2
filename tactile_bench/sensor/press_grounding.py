"""Ground a sensor profile on real ball presses: fit on half the presses, test on the rest.

The real frames of a Taxim calibration pack (``data.ball_presses``) give real (depth, image)
pairs. ``fit_sensor`` measures from the fitting half what a surrogate profile needs: the
no-contact field (cosine coefficients of the real no-contact frame), the gel's elastic spread
(chosen by two-fold cross-validation inside the fitting half), the optical response (ridge
least squares, ``response_fit``), the LED azimuths and the frame-to-frame camera noise.
``press_report`` then compares, on the held-out presses only, the surrogate profile and the
simple simulator against the real frames, frame by frame.

Works on tensors; the command layer loads the packs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from tactile_bench.effects import get_effect
from tactile_bench.effects.base import EffectContext
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.grounding import fit_background_dct
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.response_fit import fit_response, predict_delta

#: elastic spreads tried (mm, the largest Gaussian of Taxim's pyramid; 0 = rigid)
SIGMA_GRID = (0.0, 0.3, 0.6, 0.9, 1.2, 1.6)
BACKGROUND_K = 8  # cosine terms per axis of the fitted no-contact field
NOISE_SIZE = 64  # the project's image size, at which the camera noise is measured


def spread(depth: torch.Tensor, sigma_mm: float, gel_mm: tuple[float, float]) -> torch.Tensor:
    """The gel surface under ``elastic_spread`` at ``sigma_mm`` (deterministic)."""
    if sigma_mm <= 0:
        return depth
    effect = get_effect("elastic_spread")
    ctx = EffectContext(gel_mm[0], gel_mm[1], False)
    return effect.apply(depth, effect.validate({"sigma_mm": sigma_mm}), None, ctx).clamp(min=0.0)


def _heldout_mse(
    depth: torch.Tensor,
    real: torch.Tensor,
    background: torch.Tensor,
    gel_mm: tuple[float, float],
    fit_idx: Sequence[int],
    test_idx: Sequence[int],
) -> float:
    w = fit_response(depth[list(fit_idx)], (real - background)[list(fit_idx)], gel_mm)
    pred = background + predict_delta(depth[list(test_idx)], w, gel_mm)
    return float(((pred.clamp(0, 255) - real[list(test_idx)]) ** 2).mean())


def led_azimuths(weights: np.ndarray) -> tuple[float, float, float]:
    """Azimuth (deg, image axes) of each channel's light: opposite to the uphill direction
    of its largest first-harmonic response at the frame centre (as for the DIGIT)."""
    cos1, sin1 = weights[2, :, 0], weights[3, :, 0]  # t * cos(phi), t * sin(phi); pos term 1
    return tuple(
        round((math.degrees(math.atan2(s, c)) + 180.0) % 360.0, 1)
        for c, s in zip(cos1, sin1, strict=True)
    )


def frame_noise(real: torch.Tensor, background: torch.Tensor, depth: torch.Tensor) -> float:
    """Std (0-255) of real minus no-contact frame far from any contact, at NOISE_SIZE.

    Pixels farther than a quarter of the frame from the contact only differ by camera noise
    and drift between the two exposures; the difference holds two frames' noise, hence
    the 1 / sqrt(2).
    """
    size = (NOISE_SIZE, NOISE_SIZE)
    r, b = F.adaptive_avg_pool2d(real, size), F.adaptive_avg_pool2d(background[None], size)
    touched = F.adaptive_max_pool2d((depth > 0).float(), size)
    far = F.max_pool2d(touched, 2 * (NOISE_SIZE // 4) + 1, 1, NOISE_SIZE // 4) == 0
    diff = (r - b)[far.expand_as(r)]
    return float(diff.std() / math.sqrt(2)) if diff.numel() > 100 else 0.0


def fit_sensor(
    depth: torch.Tensor,
    real: torch.Tensor,
    background: torch.Tensor,
    gel_mm: tuple[float, float],
) -> dict:
    """Everything a surrogate profile takes from real presses, from these presses only.

    ``depth`` (N, 1, H, W) mm, ``real`` (N, 3, H, W), ``background`` (3, H, W): the fitting
    half, at the fitting size. The spread is chosen by two-fold cross-validation inside it.
    """
    n = depth.shape[0]
    folds = (list(range(0, n, 2)), list(range(1, n, 2)))
    cv = {}
    for sigma in SIGMA_GRID:
        surf = spread(depth, sigma, gel_mm)
        cv[sigma] = 0.5 * sum(
            _heldout_mse(surf, real, background, gel_mm, a, b) for a, b in (folds, folds[::-1])
        )
    sigma = min(cv, key=cv.get)
    weights = fit_response(spread(depth, sigma, gel_mm), real - background, gel_mm)
    dct = fit_background_dct(background.permute(1, 2, 0).double().numpy(), BACKGROUND_K)
    return {
        "gel_mm": (round(gel_mm[0], 4), round(gel_mm[1], 4)),
        "elastic_sigma_mm": sigma,
        "cv_mse": {str(k): round(v, 2) for k, v in cv.items()},
        "read_noise": round(frame_noise(real, background, depth), 2),
        "led_azimuth_deg": led_azimuths(weights),
        "response_weights": np.round(weights, 3).tolist(),
        "background_dct": np.round(dct, 2).tolist(),
        "n_presses": n,
    }


def format_fit_module(fits: dict[str, dict], source: str) -> str:
    """The text of ``effects/_taxim_fit.py`` for ``fits`` (sensor name -> ``fit_sensor``)."""
    lines = [
        '"""GelSight and GelSight Mini optics, fitted to the real frames the ``taxim`` package',
        "ships.",
        "",
        f"Source: {source}.",
        "Each sensor's numbers come from its even-numbered presses only",
        "(``tactile_bench.sensor.press_grounding.fit_sensor``); the odd ones are held out for",
        "``ground --profile``. Regenerate with ``python -m tactile_bench ground --profile",
        "gelsight --refit > tactile_bench/effects/_taxim_fit.py``.",
        '"""',
        "",
        "# ruff: noqa: E501",
        "# fmt: off",
        "SENSORS: dict[str, dict] = {",
    ]
    for name, fit in fits.items():
        lines.append(f"    {name!r}: {{")
        for key in (
            "gel_mm",
            "elastic_sigma_mm",
            "read_noise",
            "led_azimuth_deg",
            "n_presses",
            "cv_mse",
            "background_dct",
            "response_weights",
        ):
            lines.append(f"        {key!r}: {fit[key]!r},")
        lines.append("    },")
    lines += ["}", "# fmt: on", ""]
    return "\n".join(lines)


def contact_mask(depth: torch.Tensor, reach: float = 2.0) -> torch.Tensor:
    """(N, 1, H, W) pixels within ``reach`` contact radii of each contact's centre."""
    touched = (depth > 0).float()
    area = touched.sum((2, 3), keepdim=True).clamp(min=1)
    h, w = depth.shape[-2:]
    yy, xx = torch.meshgrid(torch.arange(h).float(), torch.arange(w).float(), indexing="ij")
    cy = (touched * yy).sum((2, 3), keepdim=True) / area
    cx = (touched * xx).sum((2, 3), keepdim=True) / area
    # the contact is an ellipse in pixels when the frame is squashed: scale each axis
    ry = (touched.amax(3, keepdim=True).sum(2, keepdim=True) / 2).clamp(min=1)
    rx = (touched.amax(2, keepdim=True).sum(3, keepdim=True) / 2).clamp(min=1)
    return (((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2) <= reach**2


def sim_render(depth: torch.Tensor, background: torch.Tensor, gel: GelSpec) -> torch.Tensor:
    """The simple simulator (TACTO-like, noise-free) composited on the real no-contact frame."""
    return SimOptics().render(depth, background, None, gel)


def press_metrics(pred: torch.Tensor, real: torch.Tensor, mask: torch.Tensor) -> list[dict]:
    """Per frame: MSE and SSIM over the frame, MSE inside the contact ``mask``."""
    rows = []
    for i in range(len(real)):
        m = ssim_mse(pred[i : i + 1], real[i : i + 1])
        sel = mask[i].expand_as(real[i])
        m["contact_mse"] = float(((pred[i] - real[i])[sel] ** 2).mean())
        rows.append({k: round(v, 4) for k, v in m.items()})
    return rows


def summarise(rows: list[dict]) -> dict:
    """Mean and standard deviation of each metric over the frames."""
    keys = rows[0].keys() if rows else ()
    return {
        k: {
            "mean": round(float(np.mean([r[k] for r in rows])), 4),
            "std": round(float(np.std([r[k] for r in rows])), 4),
        }
        for k in keys
    }


def press_figure(
    depth: torch.Tensor, columns: dict[str, torch.Tensor], out: Path, n: int = 4
) -> Path:
    """A grid: one row per press, columns depth | each image set (e.g. sim, surrogate, real)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = min(n, len(depth))
    idx = np.linspace(0, len(depth) - 1, n).round().astype(int)
    cols = 1 + len(columns)
    fig, axes = plt.subplots(n, cols, figsize=(2.2 * cols, 2.2 * n), squeeze=False)
    for r, i in enumerate(idx):
        axes[r, 0].imshow(depth[i, 0].numpy(), cmap="viridis")
        for c, (name, images) in enumerate(columns.items(), start=1):
            axes[r, c].imshow(images[i].permute(1, 2, 0).clamp(0, 255).byte().numpy())
            if r == 0:
                axes[r, c].set_title(name, fontsize=9)
        if r == 0:
            axes[r, 0].set_title("depth", fontsize=9)
        for a in axes[r]:
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
