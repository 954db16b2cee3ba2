"""Effects acting on the camera: lens, sensor, image processor and video stream.

They act on the image (N, 3, S, S), 0..255, at the model resolution, in the order defocus
-> vignetting -> noise -> gamma / white balance -> compression. Noise levels refer to frames
as stored (after the paper's resize to S x S). The deterministic ones also act on the
unit's no-contact frame.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch
from PIL import Image

from tactile_bench.effects.base import (
    Draw,
    Effect,
    EffectContext,
    Param,
    ParamValue,
    as_tensor,
    per_sub_batch,
    scalar,
)
from tactile_bench.effects.draws import randn
from tactile_bench.effects.kernels import gaussian_blur, pixel_grid, resize_matrix


class DefocusBlur(Effect):
    name = "defocus_blur"
    acts_on = "camera"
    description = (
        "The DIGIT's fixed-focus lens sits about 22 mm behind a domed gel several mm thick, "
        "so not all of the surface is in focus: edges are spread by a point-spread function "
        "wider than a pixel. Modelled as an isotropic Gaussian PSF on the gel plane."
    )
    _src = "estimate: ~1.5 QVGA px (0.11 mm) PSF of a fixed-focus M7 lens over a 4.6 mm domed gel"
    params = (Param("sigma_mm", "mm", 0.12, 0.0, 1.0, 0.0, _src, "PSF sigma on the gel"),)
    differentiable = ("sigma_mm",)

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        dx, dy = ctx.mm_per_px(x)
        s = as_tensor(p["sigma_mm"])
        return gaussian_blur(x, s / dx, s / dy)


class Vignetting(Effect):
    name = "vignetting"
    acts_on = "camera"
    description = (
        "Brightness falls off towards the edges of the view: off-axis light reaches the "
        "sensor obliquely (the cos^4 law) and the LEDs light the rim less. Relative to the "
        "measured frame (which already carries its own), a unit's extra falloff follows "
        "1 / (1 + a r^2)^2, parametrised by the light lost in the corners."
    )
    _src = "cos^4 law; corner falloff of ~60 deg FOV lenses 10-40% (estimate of unit spread)"
    params = (Param("corner_loss", "1", 0.12, 0.0, 0.6, 0.0, _src, "light lost at the corner"),)
    differentiable = ("corner_loss",)

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        uu, vv = pixel_grid(x.shape[-2], x.shape[-1], x.device)
        xm, ym = uu * ctx.width_mm / 2, vv * ctx.height_mm / 2
        r2 = (xm**2 + ym**2) / ((ctx.width_mm / 2) ** 2 + (ctx.height_mm / 2) ** 2)
        a = (1 - as_tensor(p["corner_loss"])).rsqrt() - 1
        return x / (1 + a * r2) ** 2


class CameraNoise(Effect):
    name = "camera_noise"
    acts_on = "camera"
    stochastic = True
    description = (
        "Sensor noise is not a fixed Gaussian: photon shot noise grows with the signal "
        "(variance proportional to it) on top of signal-independent read noise. "
        "Poisson-Gaussian model, var = read^2 + shot_gain * signal (in 0-255 units), drawn "
        "with the reparameterisation trick so it stays differentiable in its parameters."
    )
    _read = (
        "../shared/real/digit_background_240x320.jpg: high-pass residual std 1.0-1.5 DN "
        "(a lower bound after JPEG)"
    )
    _shot = "estimate: ~5k e- full well over 8 bits -> ~20 e-/DN -> 0.05 DN per DN"
    params = (
        Param("read_noise", "DN", 1.5, 0.0, 20.0, 0.0, _read, "signal-independent std"),
        Param("shot_gain", "DN", 0.06, 0.0, 1.0, 0.0, _shot, "variance per unit of signal"),
    )
    differentiable = ("read_noise", "shot_gain")

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        return [("randn", (n, 3, *image_hw))]

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        if not ctx.stochastic:
            return x
        noise = randn(tuple(x.shape), generator)
        read2, shot = as_tensor(p["read_noise"]) ** 2, as_tensor(p["shot_gain"])

        def noisy(x: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
            if x.requires_grad or read2.requires_grad or shot.requires_grad:
                return x + torch.sqrt(read2 + shot * x.clamp(min=0.0) + 1e-12) * noise
            # the same sums in place: std = sqrt(read^2 + shot * x+ + 1e-12)
            std = x.clamp(min=0.0).mul_(shot).add_(read2).add_(1e-12).sqrt_()
            return std.mul_(noise).add_(x)

        return per_sub_batch(noisy, x, noise)


class GammaWhiteBalance(Effect):
    name = "gamma_white_balance"
    acts_on = "camera"
    description = (
        "The camera's image processor is not linear and not neutral: auto white balance "
        "scales red and blue against green, and a tone curve (gamma) compresses highlights. "
        "The simulator adds its shading linearly onto the background, so the same contact "
        "changes the real image by different amounts on bright and dark parts of the field."
    )
    _src = "estimate: UVC auto white balance drift ~5%; ISP tone curves deviate ~10% in gamma"
    params = (
        Param("gamma", "1", 1.1, 0.5, 2.0, 1.0, _src, "tone-curve exponent (out = in^(1/g))"),
        Param("wb_r", "1", 1.04, 0.7, 1.3, 1.0, _src, "red white-balance gain"),
        Param("wb_b", "1", 0.95, 0.7, 1.3, 1.0, _src, "blue white-balance gain"),
    )
    differentiable = ("gamma", "wb_r", "wb_b")

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        one = torch.ones((), device=x.device)
        wb = torch.stack([as_tensor(p["wb_r"], x), one, as_tensor(p["wb_b"], x)]).view(1, 3, 1, 1)
        inv_gamma = 1.0 / as_tensor(p["gamma"], x)
        if x.requires_grad or inv_gamma.requires_grad or wb.requires_grad:
            return per_sub_batch(
                lambda x: 255.0 * (x * wb / 255.0).clamp(1e-4, 1.0) ** inv_gamma, x
            )
        g = float(1.0 / as_tensor(p["gamma"]).cpu())  # float32, as the tensor path rounds it
        return per_sub_batch(
            lambda x: (x * wb).div_(255.0).clamp_(1e-4, 1.0).pow_(g).mul_(255.0), x
        )

    def invert(self, y: torch.Tensor, p: Mapping[str, ParamValue]) -> torch.Tensor:
        """The light that gave the processed frame ``y`` (the curve is pointwise and
        monotone): a measured frame's level before the camera's processing, where a contact's
        change of light adds. Clipped levels stay at the clip."""
        one = torch.ones((), device=y.device)
        wb = torch.stack([as_tensor(p["wb_r"], y), one, as_tensor(p["wb_b"], y)]).view(1, 3, 1, 1)
        return 255.0 * (y / 255.0).clamp(1e-4, 1.0) ** as_tensor(p["gamma"], y) / wb


# --------------------------------------------------------------------------- JPEG
# ITU T.81 Annex K tables (luminance, chrominance), scaled by quality as libjpeg does.
_Q_LUMA = (
    (16, 11, 10, 16, 24, 40, 51, 61), (12, 12, 14, 19, 26, 58, 60, 55),
    (14, 13, 16, 24, 40, 57, 69, 56), (14, 17, 22, 29, 51, 87, 80, 62),
    (18, 22, 37, 56, 68, 109, 103, 77), (24, 35, 55, 64, 81, 104, 113, 92),
    (49, 64, 78, 87, 103, 121, 120, 101), (72, 92, 95, 98, 112, 100, 103, 99),
)  # fmt: skip


def _chroma_table() -> torch.Tensor:
    q = torch.full((8, 8), 99.0)
    q[:4, :4] = torch.tensor(
        ((17, 18, 24, 47), (18, 21, 26, 66), (24, 26, 56, 99), (47, 66, 99, 99)),
        dtype=torch.float32,
    )
    return q


def quant_tables(quality: float) -> tuple[torch.Tensor, torch.Tensor]:
    """libjpeg's quality scaling of the Annex K tables (baseline, clamped to 1..255)."""
    q = min(max(int(round(quality)), 1), 100)
    scale = 5000 / q if q < 50 else 200 - 2 * q
    tabs = []
    for base in (torch.tensor(_Q_LUMA, dtype=torch.float32), _chroma_table()):
        tabs.append(torch.floor((base * scale + 50) / 100).clamp(1, 255))
    return tabs[0], tabs[1]


@lru_cache(maxsize=1)
def dct_matrix() -> torch.Tensor:
    k = torch.arange(8, dtype=torch.float32)
    d = torch.cos(math.pi * (2 * k[None, :] + 1) * k[:, None] / 16) * math.sqrt(2 / 8)
    d[0] /= math.sqrt(2)
    return d


def _round_ste(x: torch.Tensor) -> torch.Tensor:
    return x + (torch.round(x) - x).detach()


@dataclass(frozen=True)
class _Rows:
    """A banded (M, K) matrix applied along rows: groups of ``g`` output rows each read a
    window of ``w`` consecutive input rows, so the product is one batched small GEMM."""

    index: torch.Tensor | None  # (G * w,) input rows window by window; None: windows tile x
    blocks: torch.Tensor  # (G, g, w)

    @classmethod
    def of(cls, m: torch.Tensor) -> _Rows:
        """Split ``m`` into the row groups that cost least (multiply-adds + rows copied)."""
        rows, cols = m.shape
        best: tuple[int, torch.Tensor, torch.Tensor] | None = None
        for g in (d for d in range(1, rows + 1) if rows % d == 0):
            used = m.reshape(rows // g, g, cols).abs().amax(1) > 0  # (G, K)
            first = used.float().argmax(1)
            width = int((cols - used.flip(1).float().argmax(1) - first).max())
            index = (first.clamp(max=cols - width)[:, None] + torch.arange(width)).reshape(-1)
            tiled = index.numel() == cols and bool((index == torch.arange(cols)).all())
            cost = rows * width + (0 if tiled else 8 * index.numel())
            if best is None or cost < best[0]:
                best = (cost, index, m.reshape(rows // g, g, cols))
        _, index, grouped = best
        blocks = torch.gather(
            grouped, 2, index.view(len(grouped), 1, -1).expand(grouped.shape[:2] + (-1,))
        )
        tiled = index.numel() == cols
        return cls(None if tiled else index, blocks.contiguous())

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """``m @ x`` for x (K, B, C), the batch between rows and columns.

        That layout makes each group's window one (w, B * C) matrix, so the product is G
        GEMMs over the whole batch rather than G * B tiny ones (bmm's per-matrix overhead
        was most of the JPEG's cost)."""
        groups, g, width = self.blocks.shape
        _, b, c = x.shape
        windows = x if self.index is None else x.index_select(0, self.index)
        return torch.bmm(self.blocks, windows.reshape(groups, width, b * c)).view(-1, b, c)


@dataclass(frozen=True)
class _PlaneCodec:
    """JPEG of one plane size as matrices: resize up, 8 x 8 block DCT (forward ``rows``/
    ``cols``), quantisation table, inverse DCT and area-average back (``back_rows``/``back_cols``).
    Resizes and DCTs are linear and separable, so only the quantisation is not a product."""

    rows: _Rows  # (hh, s_h): upsample then DCT along y
    cols: torch.Tensor  # (s_w, ww): upsample then DCT along x, transposed
    table: torch.Tensor  # (hh, 1, ww) quantisation step of each coefficient
    back_rows: _Rows  # (s_h, hh): inverse DCT then area-average along y
    back_cols: torch.Tensor  # (ww, s_w), transposed

    def __call__(self, plane: torch.Tensor) -> torch.Tensor:
        """(s_h, B, s_w) -> same, after coding at (hh, ww): rows, batch, columns (``_Rows``)."""
        s_h, b, s_w = plane.shape
        coef = self.rows((plane.reshape(-1, s_w) @ self.cols).view(s_h, b, -1))  # (hh, B, ww)
        if coef.requires_grad:
            coef = _round_ste(coef / self.table) * self.table
        else:  # in place: the coefficients are the largest tensors of the surrogate
            coef = coef.div_(self.table).round_().mul_(self.table)
        back = self.back_rows(coef)  # (s_h, B, ww)
        return (back.view(-1, back.shape[-1]) @ self.back_cols).view(s_h, b, s_w)


def _block_dct(n: int) -> torch.Tensor:
    """(n, n) block-diagonal orthonormal DCT-II of 8-sample blocks."""
    return torch.block_diag(*[dct_matrix()] * (n // 8))


@lru_cache(maxsize=16)
def _plane_codec(size: tuple[int, int], coded: tuple[int, int], table: tuple) -> _PlaneCodec:
    (s_h, s_w), (hh, ww) = size, coded
    d_h, d_w = _block_dct(hh), _block_dct(ww)
    q = torch.tensor(table, dtype=torch.float32).repeat(hh // 8, ww // 8)
    return _PlaneCodec(
        rows=_Rows.of(d_h @ resize_matrix(hh, s_h, "bilinear")),
        cols=(d_w @ resize_matrix(ww, s_w, "bilinear")).T.contiguous(),
        table=q[:, None],
        back_rows=_Rows.of(resize_matrix(s_h, hh, "area") @ d_h.T),
        back_cols=(resize_matrix(s_w, ww, "area") @ d_w.T).T.contiguous(),
    )


_RGB_TO_YCC = torch.tensor(
    [[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]]
)
_YCC_TO_RGB = torch.tensor([[1.0, 0.0, 1.402], [1.0, -0.344136, -0.714136], [1.0, 1.772, 0.0]])


def jpeg_approx(x: torch.Tensor, quality: float, native_hw: tuple[int, int]) -> torch.Tensor:
    """Differentiable JPEG (baseline, 4:2:0) of (N, 3, S, S) 0..255 at the sensor's frame size.

    The image is resized to the native frame, compressed like libjpeg (JFIF YCbCr, Annex K
    tables, 2x2 chroma subsampling, rounding with a straight-through gradient) and resized
    back with area averaging. Not bit-exact libjpeg (no integer DCT, bilinear chroma).
    Everything but the rounding is linear and separable, so each plane is two matrix
    products to its DCT coefficients and two back (``_PlaneCodec``).
    """
    n, _, s_h, s_w = x.shape
    hh, ww = native_hw
    q_l, q_c = quant_tables(quality)
    luma = _plane_codec((s_h, s_w), (hh, ww), tuple(map(tuple, q_l.tolist())))
    chroma = _plane_codec((s_h, s_w), (hh // 2, ww // 2), tuple(map(tuple, q_c.tolist())))
    # planes in (rows, batch, columns) layout, what the codec's products want
    xt = x.permute(2, 1, 0, 3).reshape(s_h, 3, n * s_w)
    ycc = torch.matmul(_RGB_TO_YCC, xt)  # (s_h, 3, N * s_w), JFIF
    lum = luma((ycc[:, 0] - 128).view(s_h, n, s_w)) + 128
    chroma = chroma(ycc[:, 1:].reshape(s_h, 2 * n, s_w)).view(s_h, 2, n, s_w)
    if lum.requires_grad or chroma.requires_grad:
        ycc = torch.cat([lum[:, None], chroma], 1).flatten(2)
        rgb = torch.matmul(_YCC_TO_RGB, ycc).view(s_h, 3, n, s_w)
        return rgb.permute(2, 1, 0, 3).clamp(0.0, 255.0)
    # the inverse colour transform written out: R = Y + 1.402 Cr, G = Y - .34 Cb - .71 Cr,
    # B = Y + 1.772 Cb (no concatenated copy, no 3 x 3 GEMM per pixel)
    cb, cr = chroma[:, 0], chroma[:, 1]
    rgb = lum[:, None].repeat(1, 3, 1, 1)
    m = _YCC_TO_RGB.tolist()
    for c in range(3):
        if m[c][1]:
            rgb[:, c].add_(cb, alpha=m[c][1])
        if m[c][2]:
            rgb[:, c].add_(cr, alpha=m[c][2])
    return rgb.clamp_(0.0, 255.0).permute(2, 1, 0, 3).contiguous()


def libjpeg(x: torch.Tensor, quality: float) -> torch.Tensor:
    """(N, 3, H, W) 0..255 frames stored as baseline JPEG files and read back, by the
    encoder that writes datasets' files (libjpeg through Pillow: 4:2:0, Annex K tables
    scaled by ``quality``). Exact where ``jpeg_approx`` approximates; the gradient passes
    straight through (as the approximation's rounding does)."""
    pixels = x.detach().clamp(0.0, 255.0).round().to(torch.uint8).permute(0, 2, 3, 1).cpu().numpy()
    out = []
    for frame in pixels:
        buf = io.BytesIO()
        Image.fromarray(frame).save(buf, format="JPEG", quality=int(round(quality)))
        with Image.open(buf) as im:
            out.append(torch.from_numpy(np.asarray(im.convert("RGB")).copy()))
    coded = torch.stack(out).permute(0, 3, 1, 2).to(x.device, x.dtype)
    return x + (coded - x).detach() if x.requires_grad else coded


class StreamCompression(Effect):
    name = "jpeg"
    acts_on = "camera"
    description = (
        "A DIGIT streams MJPEG over USB: every frame is JPEG-compressed at the sensor's "
        "320 x 240 before anyone resizes it, which quantises fine detail in 8 x 8 blocks and "
        "halves chroma resolution. Implemented as a differentiable DCT-quantisation "
        "approximation of baseline libjpeg (not a call to a real encoder), at the native "
        "240 x 320 portrait frame, then resized back."
    )
    _src = "estimate: UVC MJPEG streams of small USB cameras run at quality ~80-90"
    params = (Param("quality", "1", 85.0, 10.0, 100.0, 100.0, _src, "JPEG quality (100 = off)"),)
    differentiable = ()
    native_hw = (320, 240)
    chunk = 8  # images per pass: the 320 x 240 coefficients then stay in cache

    def _apply(
        self,
        x: torch.Tensor,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> torch.Tensor:
        if not len(x):
            return x
        q = scalar(p["quality"])
        return per_sub_batch(lambda c: jpeg_approx(c, q, self.native_hw), x, size=self.chunk)
