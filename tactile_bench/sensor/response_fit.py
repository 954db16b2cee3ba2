"""Fit a sensor's optical response from real (depth, image) pairs, as Taxim calibrates one.

Taxim (Si & Yuan 2022) presses a ball of known size across the gel and tabulates the colour
change against the surface gradient (magnitude and direction) with a quadratic field over the
pixel position. We fit the same quantity in the compact form the surrogate renders with
(``effects.optics``: powers of the slope angle times direction harmonics, each with a
quadratic position field; 22 x 3 x 6 numbers) by ridge least squares over every pixel of
the given frames. Works from tensors only: any sensor, any source of pairs.
"""

from __future__ import annotations

import numpy as np
import torch

from tactile_bench.effects.base import EffectContext
from tactile_bench.effects.kernels import pixel_grid, surface_gradient
from tactile_bench.effects.optics import (
    CONTACT_OFFSET_MM,
    position_basis,
    response_features,
    response_fields,
    response_image,
)

RIDGE = 1e-3  # relative to the mean diagonal of the normal matrix: keeps unseen slopes tame


def response_design(surface: torch.Tensor, gel_mm: tuple[float, float]) -> torch.Tensor:
    """(N, H, W, F * 6) regressors of the compact model for gel surfaces (N, 1, H, W), mm."""
    ctx = EffectContext(gel_mm[0], gel_mm[1], False)
    gx, gy = surface_gradient(surface.float(), ctx)
    contact = (surface.float() / CONTACT_OFFSET_MM).clamp(0.0, 1.0)
    feats = response_features(gx[:, 0], gy[:, 0], contact[:, 0])  # (N, H, W, F)
    uu, vv = pixel_grid(*surface.shape[-2:], surface.device)
    pos = position_basis(uu, vv)  # (H, W, 6)
    return (feats[..., :, None] * pos[None, :, :, None, :]).flatten(-2)


def fit_response(
    surface: torch.Tensor,
    delta: torch.Tensor,
    gel_mm: tuple[float, float],
    ridge: float = RIDGE,
    chunk: int = 4,
) -> np.ndarray:
    """Weights (F, 3, 6) so that the compact model maps ``surface`` to ``delta`` (N, 3, H, W).

    Normal equations of ``chunk`` frames at a time in float32 (a few thousand rows of
    bounded features: relative error ~1e-5), summed in float64 (memory stays at a few frames
    whatever N is), then a ridge-regularised solve in float64. The diagnosis refits this
    lookup under every gel geometry it tries, so this cost is paid dozens of times: float32
    products over every pixel (flat pixels add zeros) against float64 over the contact pixels
    gathered out, ``scripts/bench_response_fit.py`` measures both.
    """
    if surface.shape[0] != delta.shape[0] or surface.shape[-2:] != delta.shape[-2:]:
        raise ValueError(f"surface {tuple(surface.shape)} and delta {tuple(delta.shape)} differ")
    n_cols = response_design(surface[:1, :, :2, :2], gel_mm).shape[-1]
    xtx = torch.zeros(n_cols, n_cols, dtype=torch.float64, device=surface.device)
    xty = torch.zeros(n_cols, 3, dtype=torch.float64, device=surface.device)
    for k in range(0, surface.shape[0], chunk):
        x = response_design(surface[k : k + chunk], gel_mm).reshape(-1, n_cols)
        y = delta[k : k + chunk].permute(0, 2, 3, 1).reshape(-1, 3).float()
        xtx += (x.T @ x).double()
        xty += (x.T @ y).double()
    return solve_response(xtx, xty, ridge)


def solve_response(xtx: torch.Tensor, xty: torch.Tensor, ridge: float = RIDGE) -> np.ndarray:
    """Weights (F, 3, 6) from summed normal equations ``xtx`` (C, C) and ``xty`` (C, 3): the
    ridge-regularised solve ``fit_response`` ends with, for callers that sum them their way."""
    if not bool(torch.diagonal(xtx).gt(0).any()):
        raise ValueError("fit_response: no pixel has a contact or a slope to fit on")
    n_cols = xtx.shape[0]
    lam = ridge * float(torch.diagonal(xtx).mean())
    w = torch.linalg.solve(xtx + lam * torch.eye(n_cols, dtype=xtx.dtype, device=xtx.device), xty)
    n_feat = w.shape[0] // 6
    return w.reshape(n_feat, 6, 3).permute(0, 2, 1).cpu().numpy()  # (F, 3, 6)


def pair_normal_equations(
    surface: torch.Tensor, delta: torch.Tensor, gel_mm: tuple[float, float], chunk: int = 4
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each pair's normal equations, (N, C, C) and (N, C, 3) in float64, as ``fit_response``
    sums them: a cross-validation fits every fold from one pass (the sum over the pairs
    it trains on) instead of rebuilding the design once per fold."""
    if surface.shape[0] != delta.shape[0] or surface.shape[-2:] != delta.shape[-2:]:
        raise ValueError(f"surface {tuple(surface.shape)} and delta {tuple(delta.shape)} differ")
    xtx, xty = [], []
    for k in range(0, surface.shape[0], chunk):
        x = response_design(surface[k : k + chunk], gel_mm).flatten(1, 2)  # (n, H*W, C)
        y = delta[k : k + chunk].permute(0, 2, 3, 1).flatten(1, 2).float()  # (n, H*W, 3)
        xtx.append((x.transpose(1, 2) @ x).double())
        xty.append((x.transpose(1, 2) @ y).double())
    return torch.cat(xtx), torch.cat(xty)


def predict_delta(
    surface: torch.Tensor, weights: np.ndarray | torch.Tensor, gel_mm: tuple[float, float]
) -> torch.Tensor:
    """Colour change (N, 3, H, W) of the compact model with ``weights`` (F, 3, 6).

    The surrogate's own fast path (``effects.optics.response_image``): no (N, H, W, F * 6)
    design is ever held, which lets the diagnosis render it at every fit step.
    """
    w = torch.as_tensor(weights, dtype=torch.float32, device=surface.device)
    ctx = EffectContext(gel_mm[0], gel_mm[1], False)
    gx, gy = surface_gradient(surface.float(), ctx)
    contact = (surface.float() / CONTACT_OFFSET_MM).clamp(0.0, 1.0)
    fields = response_fields(w, *surface.shape[-2:])
    return response_image(gx[:, 0], gy[:, 0], contact[:, 0], fields)
