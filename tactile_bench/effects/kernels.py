"""Numeric kernels the effects and the renderers share: blur, pooling, resize, pixel grid,
shift, surface slope.

They are not part of what an effect is (``base``), and ``sensor/`` and ``diagnose/`` use
them without any effect, so they live here rather than in the interface module. Each is a
plain function of tensors (and an ``EffectContext`` for the gel's extent in mm).
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
import torch.nn.functional as F

from tactile_bench.effects.base import EffectContext, ParamValue, as_tensor, scalar


def gaussian_kernel1d(sigma_px: torch.Tensor, radius: int) -> torch.Tensor:
    """Normalised 1-D Gaussian taps (2 radius + 1), differentiable in ``sigma_px``."""
    t = torch.arange(-radius, radius + 1, dtype=torch.float32)
    s = sigma_px.clamp(min=1e-3)
    k = torch.exp(-0.5 * (t / s) ** 2)
    return k / k.sum()


def gaussian_blur(
    x: torch.Tensor, sigma_x_px: torch.Tensor, sigma_y_px: torch.Tensor, max_radius: int = 64
) -> torch.Tensor:
    """Separable Gaussian blur of (N, C, H, W) with reflect padding; sigma in pixels.

    Wide blurs (sigma > 4 px on both axes) run on a 2x area-downsampled copy and are
    upsampled back: same result to ~1% for a smooth field. The whole 1-D blur of each axis
    (padding, taps, upsampling) is one matrix, so the blur is two GEMMs, ``Ly @ x @ Lx^T``
    (after the 2x area pooling, for a wide one): at these sizes (<= a few hundred px)
    faster on CPU than a 1-channel ``conv2d`` (docs/results/code_figures.md), and
    differentiable in sigma through the matrices. Narrow blurs (taps within
    ``SMALL_BLUR_RADIUS`` px) of fixed sigma outside autograd are shifted adds of the same
    taps instead (``_blur_by_taps``): the dense GEMMs spend H + W multiply-adds a pixel
    whatever the radius.
    """
    h, w = x.shape[-2], x.shape[-1]
    taps = _small_blur_taps(h, w, sigma_x_px, sigma_y_px, max_radius, x)
    if taps is not None:
        return _blur_by_taps(x, *taps)
    ly, lx, pooled = _blur_factors_for(h, w, sigma_x_px, sigma_y_px, max_radius)
    if pooled:  # pool first: the GEMMs then run on a quarter of the pixels
        x = area_pool(x, 2**pooled)
    return torch.matmul(ly.to(x), torch.matmul(x, lx.to(x).T))


#: blurs whose taps reach at most this far (px) on both axes run as shifted adds
SMALL_BLUR_RADIUS = 5


def _small_blur_taps(
    h: int,
    w: int,
    sigma_x_px: ParamValue,
    sigma_y_px: ParamValue,
    max_radius: int,
    x: torch.Tensor,
) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """(x taps, y taps) of a narrow blur of fixed sigma outside autograd, else None."""
    if x.requires_grad or x.dtype != torch.float32 or x.dim() != 4:
        return None
    if any(isinstance(s, torch.Tensor) and s.requires_grad for s in (sigma_x_px, sigma_y_px)):
        return None
    return small_blur_taps(h, w, scalar(sigma_x_px), scalar(sigma_y_px), max_radius)


@lru_cache(maxsize=64)
def small_blur_taps(
    h: int, w: int, sx: float, sy: float, max_radius: int
) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """The (x, y) taps of a narrow blur that ``gaussian_blur`` runs as shifted adds, or None
    when the blur is wide and takes the pooled matrix path instead (cached by its sizes)."""
    if max(sx, sy) > 4 or min(h, w) < 2:  # wide: the pooled GEMM path
        return None
    rx = min(max_radius, max(1, math.ceil(3.0 * sx)), w - 1)
    ry = min(max_radius, max(1, math.ceil(3.0 * sy)), h - 1)
    if max(rx, ry) > SMALL_BLUR_RADIUS:
        return None
    kx = gaussian_kernel1d(torch.tensor(sx), rx)
    ky = gaussian_kernel1d(torch.tensor(sy), ry)
    return tuple(kx.tolist()), tuple(ky.tolist())


def _blur_by_taps(x: torch.Tensor, kx: tuple[float, ...], ky: tuple[float, ...]) -> torch.Tensor:
    """The reflect-padded separable blur as a weighted sum of shifted slices, x then y.

    The same taps as ``gaussian_blur``'s matrices (equal to float rounding); for a few taps
    an add each over the image is ~2-4x cheaper than the two dense GEMMs, which spend H + W
    multiply-adds a pixel whatever the radius.
    """
    for dim, k in ((-1, kx), (-2, ky)):
        r = (len(k) - 1) // 2
        pad = (r, r, 0, 0) if dim == -1 else (0, 0, r, r)
        xp = F.pad(x, pad, mode="reflect")
        size = x.shape[dim]
        out = xp.narrow(dim, 0, size) * k[0]
        for t in range(1, 2 * r + 1):
            out.add_(xp.narrow(dim, t, size), alpha=k[t])
        x = out
    return x


def area_pool(x: torch.Tensor, factor: int) -> torch.Tensor:
    """``F.avg_pool2d(x, factor)`` of (N, C, H, W), H and W multiples of ``factor``.

    The same sums in the same order (so the same floats), as strided adds: faster on CPU
    than torch's pooling kernel on the one-channel depth maps it pools most, as fast on
    images (docs/results/code_figures.md).
    """
    n, c, h, w = x.shape
    if h % factor or w % factor or x.requires_grad:
        return F.avg_pool2d(x, factor)
    v = x.view(n, c, h // factor, factor, w // factor, factor)
    out = v[:, :, :, 0, :, 0].clone()
    for i in range(factor):
        for j in range(factor):
            if i or j:
                out += v[:, :, :, i, :, j]
    return out.div_(factor * factor)


def blur_matrices(
    h: int, w: int, sigma_x_px: ParamValue, sigma_y_px: ParamValue, max_radius: int = 64
) -> tuple[torch.Tensor, torch.Tensor]:
    """(My (H, H), Mx (W, W)) of ``gaussian_blur``; cached unless a sigma is being fitted."""
    ly, lx, pooled = _blur_factors_for(h, w, sigma_x_px, sigma_y_px, max_radius)
    for _ in range(pooled):
        ly = ly @ _pool_matrix(ly.shape[1] * 2)
        lx = lx @ _pool_matrix(lx.shape[1] * 2)
    return ly, lx


def _blur_factors_for(
    h: int, w: int, sigma_x_px: ParamValue, sigma_y_px: ParamValue, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    sx, sy = as_tensor(sigma_x_px), as_tensor(sigma_y_px)
    if sx.requires_grad or sy.requires_grad:
        return _blur_factors(h, w, sx, sy, max_radius)
    return _cached_blur_factors(h, w, float(sx), float(sy), max_radius)


@lru_cache(maxsize=64)
def _cached_blur_factors(
    h: int, w: int, sx: float, sy: float, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    return _blur_factors(h, w, torch.tensor(sx), torch.tensor(sy), max_radius)


def _blur_factors(
    h: int, w: int, sx: torch.Tensor, sy: torch.Tensor, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(Ly (H, H'), Lx (W, W'), k): the blur is ``Ly @ pool_k(x) @ Lx^T``, pool_k the
    2^k x 2^k area average (H' = H / 2^k)."""
    wide = float(sx.detach()) > 4 and float(sy.detach()) > 4 and min(h, w) >= 16
    if wide and h % 2 == 0 and w % 2 == 0:
        # the 2x2 box already blurs by sqrt(1/12) px (at full res); take it off
        sx2 = torch.sqrt((sx**2 - 1 / 12).clamp(min=1e-6)) / 2
        sy2 = torch.sqrt((sy**2 - 1 / 12).clamp(min=1e-6)) / 2
        ly, lx, k = _blur_factors(h // 2, w // 2, sx2, sy2, max_radius)
        return _upsample_matrix(h) @ ly, _upsample_matrix(w) @ lx, k + 1
    rx = min(max_radius, max(1, math.ceil(3.0 * float(sx.detach()))), w - 1)
    ry = min(max_radius, max(1, math.ceil(3.0 * float(sy.detach()))), h - 1)
    return (
        _conv_matrix(h, gaussian_kernel1d(sy, ry)),
        _conv_matrix(w, gaussian_kernel1d(sx, rx)),
        0,
    )


def _conv_matrix(n: int, k: torch.Tensor) -> torch.Tensor:
    """(n, n) matrix of the reflect-padded correlation with taps ``k``: the conv of an identity."""
    return conv1d_slices(torch.eye(n)[None, None], k, -1)[0, 0].T


@lru_cache(maxsize=16)
def _pool_matrix(n: int) -> torch.Tensor:
    """(n / 2, n): 2x area downsampling along one axis."""
    return torch.eye(n).reshape(n // 2, 2, n).mean(1)


@lru_cache(maxsize=16)
def _upsample_matrix(n: int) -> torch.Tensor:
    """(n, n / 2): ``F.interpolate`` bilinear (align_corners False) 2x upsampling along one axis."""
    return resize_matrix(n, n // 2, "bilinear")


def resize_matrix(out: int, n: int, mode: str) -> torch.Tensor:
    """(out, n) matrix of a 1-D resize, built by resizing an identity with torch's own op.

    ``mode`` is ``"bilinear"`` (``F.interpolate``, align_corners False) or ``"area"``
    (``F.adaptive_avg_pool2d``); torch's 2-D resizes are separable, so two such matrices
    reproduce them.
    """
    eye = torch.eye(n)[None, None]
    if mode == "area":
        return F.adaptive_avg_pool2d(eye, (out, n))[0, 0]
    return F.interpolate(eye, size=(out, n), mode="bilinear", align_corners=False)[0, 0]


def conv1d_slices(x: torch.Tensor, k: torch.Tensor, dim: int) -> torch.Tensor:
    """Correlate every (N, C) plane along ``dim`` with taps ``k``, reflect padding.

    The reference definition of one blur axis; ``_conv_matrix`` runs it once on an identity.
    """
    n, c, h, w = x.shape
    r = (k.numel() - 1) // 2
    pad = (r, r, 0, 0) if dim == -1 else (0, 0, r, r)
    weight = k.view(1, 1, 1, -1) if dim == -1 else k.view(1, 1, -1, 1)
    y = F.conv2d(F.pad(x.reshape(n * c, 1, h, w), pad, mode="reflect"), weight)
    return y.reshape(n, c, h, w)


@lru_cache(maxsize=32)
def pixel_grid(
    h: int, w: int, device: torch.device | str = "cpu"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised pixel-centre coordinates u (right), v (down) in [-1, 1], each (H, W), on
    ``device``.

    Cached per size and device: treat the tensors as read-only.
    """
    v = (torch.arange(h, dtype=torch.float32, device=device) + 0.5) / h * 2 - 1
    u = (torch.arange(w, dtype=torch.float32, device=device) + 0.5) / w * 2 - 1
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return uu, vv


def surface_gradient(height: torch.Tensor, ctx: EffectContext) -> tuple[torch.Tensor, torch.Tensor]:
    """Central-difference slope (dh/dx, dh/dy), mm/mm, image axes (x right, y down)."""
    dx, dy = ctx.mm_per_px(height)
    hp = F.pad(height, (1, 1, 1, 1), mode="replicate")
    gx = (hp[..., 1:-1, 2:] - hp[..., 1:-1, :-2]) / (2 * dx)
    gy = (hp[..., 2:, 1:-1] - hp[..., :-2, 1:-1]) / (2 * dy)
    return gx, gy
