"""The simple simulator's optics: TACTO's DIGIT, Phong-shaded with three ideal point lights.

TACTO (``tacto/config_digit.yml``, ``renderer.py``) renders the deformed gel with pyrender:
three point lights, red, green and blue, in a plane 17 mm behind the gel (gel at x = 22 mm,
lights at x = 5 mm from the camera), on a 20 mm circle at 30, 150 and 270 deg; camera 22 mm
behind the gel. It then subtracts its own no-contact render, scales that difference by 0.5,
low-passes it (7 x 7 Gaussian on the 240 x 320 frame, sigma ~1.4 px ~ 0.1 mm) and adds it to
a real background frame, then Gaussian noise (std 7 on 0-255). ``SimOptics`` mirrors those
steps on the depth image directly (no OpenGL), vectorised over the batch.

Frame: sensor x along the gel width (image columns), y along its height (image rows run from
+y at the top), z from the gel towards the camera; the pressed gel surface sits at z = depth.
TACTO models the gel as slightly curved; we shade it flat (the curvature only changes the
no-contact frame, which the background subtraction removes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F

from tactile_bench.effects.draws import replay_draws
from tactile_bench.sensor.depth import GelSpec

_CHUNK = 16  # images per pass of ``SimOptics.render``: a multiple of 16 (see there)
_DENSE_ABOVE = 0.5  # fraction of touched pixels above which shading everything is cheaper


def surface_normals(depth: torch.Tensor, gel: GelSpec) -> torch.Tensor:
    """Unit normals (N, 3, S, S) of the pressed gel surface z = depth, facing the camera.

    Central differences in mm (x and y pixels differ in size: 18 / S vs 24 / S mm), one-sided
    at the borders. Rows run towards -y, hence the sign flip on the row gradient.
    """
    return torch.stack(_normal_components(depth, gel), 1)


def _normal_components(
    depth: torch.Tensor, gel: GelSpec
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    dx, dy = gel.width_mm / depth.shape[-1], gel.height_mm / depth.shape[-2]
    d_row, d_col = torch.gradient(depth[:, 0], spacing=(dy, dx), dim=(-2, -1))
    inv = torch.rsqrt(d_row * d_row + d_col * d_col + 1)
    return -d_col * inv, d_row * inv, inv


def _gaussian_blur(x: torch.Tensor, sigma_px: tuple[float, float]) -> torch.Tensor:
    """Separable Gaussian blur with per-axis sigma (pixels), replicate borders.

    Written as a weighted sum of shifted slices: for the few taps needed it is several times
    faster on CPU than a grouped ``conv2d``.
    """
    for dim, sigma in ((-1, sigma_px[0]), (-2, sigma_px[1])):
        if sigma <= 0:
            continue
        r = max(1, math.ceil(3 * sigma))
        w = [math.exp(-0.5 * (t / sigma) ** 2) for t in range(-r, r + 1)]
        pad = (r, r, 0, 0) if dim == -1 else (0, 0, r, r)
        xp = F.pad(x, pad, mode="replicate")
        n = x.shape[dim]
        out = xp.narrow(dim, 0, n) * (w[0] / sum(w))
        for t in range(1, 2 * r + 1):
            out.add_(xp.narrow(dim, t, n), alpha=w[t] / sum(w))
        x = out
    return x


@dataclass(frozen=True)
class SimOptics:
    """TACTO-like optics: Phong shading with three coloured point lights, plus noise.

    Lengths in mm, intensities on the 0-255 scale. Light i lights colour channel i only
    (TACTO's colours [[1,0,0],[0,1,0],[0,0,1]]). ``ambient`` cancels in the difference with
    the flat gel but is kept so ``shade`` is a complete Phong model.
    """

    light_radius_mm: float = 20.0
    light_angles_deg: tuple[float, float, float] = (30.0, 150.0, 270.0)
    light_distance_mm: float = 17.0
    camera_distance_mm: float = 22.0
    intensity: float = 255.0
    ambient: float = 0.1
    diffuse: float = 1.0
    specular: float = 0.5
    shininess: float = 20.0
    diff_scale: float = 0.5
    blur_sigma_mm: float = 0.105
    noise_std: float = 7.0

    def light_positions(self) -> torch.Tensor:
        """(3, 3) light positions (x, y, z) in the sensor frame, mm."""
        a = torch.deg2rad(torch.tensor(self.light_angles_deg, dtype=torch.float32))
        r = self.light_radius_mm
        return torch.stack(
            [r * torch.cos(a), r * torch.sin(a), torch.full_like(a, self.light_distance_mm)], 1
        )

    def shade(self, depth: torch.Tensor, gel: GelSpec) -> torch.Tensor:
        """Phong colour (N, 3, S, S), 0-255 scale, of the gel pressed to ``depth`` (mm).

        Per pixel and light: ambient + diffuse (n.l)+ + specular ((r.v)+)^shininess, with l and
        v the directions from the surface point to the light and to the camera. The dense
        reference of what ``render`` computes (sparsely) for its colour change.
        """
        _, _, hh, ww = depth.shape
        nx, ny, nz = _normal_components(depth, gel)  # each (N, H, W)
        px, py = _pixel_centres(hh, ww, gel, depth)
        channels = self._phong(nx, ny, nz, px, py[:, None], depth[:, 0])
        return torch.stack(channels, 1).add_(self.ambient).mul_(self.intensity)

    def _phong(
        self,
        nx: torch.Tensor,
        ny: torch.Tensor,
        nz: torch.Tensor,
        px: torch.Tensor,
        py: torch.Tensor,
        pz: torch.Tensor,
        lights: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] | None = None,
    ) -> list[torch.Tensor]:
        """Diffuse + specular of each light (before ambient and intensity); inputs broadcast.

        ``lights``: (x, y, z) of each light, tensors broadcasting with the pixels (one light
        position per image); None: this optics' own ``light_positions``.
        """
        vx, vy, vz = -px, -py, self.camera_distance_mm - pz
        inv = torch.rsqrt(vx * vx + vy * vy + vz * vz)
        vx, vy, vz = vx * inv, vy * inv, vz * inv
        n_dot_v = nx * vx + ny * vy + nz * vz
        channels = []
        for lx, ly, lz in self.light_positions().tolist() if lights is None else lights:
            ax, ay, az = lx - px, ly - py, lz - pz
            inv = torch.rsqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax * inv, ay * inv, az * inv
            n_dot_l = nx * ax + ny * ay + nz * az
            # reflection r = 2 (n.l) n - l, so r.v = 2 (n.l)(n.v) - l.v
            r_dot_v = (2 * n_dot_l * n_dot_v - (ax * vx + ay * vy + az * vz)).clamp_(min=0)
            spec = _power(r_dot_v, self.shininess).mul_(n_dot_l > 0)
            channels.append(
                n_dot_l.clamp_(min=0).mul_(self.diffuse).add_(spec, alpha=self.specular)
            )
        return channels

    def shade_change(self, depth: torch.Tensor, gel: GelSpec) -> torch.Tensor:
        """``shade(depth) - shade(flat)`` (N, 3, H, W), computed only where it can be non-zero.

        A pixel whose depth and both neighbours' depths are 0 has the flat gel's normal and
        position, so its shading is exactly the flat one: contacts cover a few % of a braille
        image, so shading just the pixels in and around them is ~10x less work. Dense when
        most pixels are touched (a face of a box pressed flat: dense is then cheaper) and
        when differentiating through the depth.
        """
        n, _, hh, ww = depth.shape
        flat = _flat_shading(self, gel.width_mm, gel.height_mm, hh, ww, depth.device)
        d_row, d_col, idx, dense = _touched(depth, gel)
        if dense:
            inv = torch.rsqrt(d_row * d_row + d_col * d_col + 1)
            px, py = _pixel_centres(hh, ww, gel, depth)
            ch = self._phong(-d_col * inv, d_row * inv, inv, px, py[:, None], depth[:, 0])
            shaded = torch.stack(ch, 1).add_(self.ambient).mul_(self.intensity)
            return shaded.sub_(flat)
        out = depth.new_zeros(n, 3, hh * ww)
        if idx.numel() == 0:
            return out.view(n, 3, hh, ww)
        pix = idx % (hh * ww)
        g_row, g_col = d_row.reshape(-1)[idx], d_col.reshape(-1)[idx]
        inv = torch.rsqrt(g_row * g_row + g_col * g_col + 1)
        px, py = _pixel_centres(hh, ww, gel, depth)
        ch = self._phong(
            -g_col * inv, g_row * inv, inv, px[pix % ww], py[pix // ww], depth.reshape(-1)[idx]
        )
        values = torch.stack(ch, 0).add_(self.ambient).mul_(self.intensity)
        values.sub_(flat.reshape(3, -1)[:, pix])
        # scatter (3, M) into (N, 3, H*W): image idx // HW, channel c, pixel pix
        dest = (idx - pix) * 3 + pix  # offset of channel 0
        flat_out = out.view(-1)
        for c in range(3):
            flat_out.index_copy_(0, dest + c * hh * ww, values[c])
        return out.view(n, 3, hh, ww)

    def shade_change_lit(
        self, depth: torch.Tensor, gel: GelSpec, lights: torch.Tensor, colours: torch.Tensor
    ) -> torch.Tensor:
        """``shade_change`` with each image's own lights (N, 3, H, W), 0-255 scale.

        ``lights`` (N, 3, 3): each image's light positions (light, xyz) in mm; ``colours``
        (N, 3, 3): light i's contribution to colour channel c, intensity included (this
        optics' nominal lights: ``intensity`` times the identity). The flat gel is shaded
        under the same lights, so only the contact's change is returned; ``ambient`` cancels.
        Sparse like ``shade_change``: only touched pixels are shaded (twice: pressed, flat).
        """
        n, _, hh, ww = depth.shape
        d_row, d_col, idx, dense = _touched(depth, gel)
        px, py = _pixel_centres(hh, ww, gel, depth)
        lights, colours = lights.to(depth.dtype), colours.to(depth.dtype)
        if dense:
            lit = [tuple(lights[:, i, k, None, None] for k in range(3)) for i in range(3)]
            inv = torch.rsqrt(d_row * d_row + d_col * d_col + 1)
            pressed = self._phong(-d_col * inv, d_row * inv, inv, px, py[:, None], depth[:, 0], lit)
            zero = torch.zeros_like(inv)
            flat = self._phong(zero, zero, zero + 1, px, py[:, None], zero, lit)
            diff = torch.stack(pressed, 1).sub_(torch.stack(flat, 1))  # (N, light, H, W)
            return torch.einsum("nlhw,nlc->nchw", diff, colours)
        out = depth.new_zeros(n, 3, hh * ww)
        if idx.numel() == 0:
            return out.view(n, 3, hh, ww)
        pix = idx % (hh * ww)
        image = idx // (hh * ww)
        g_row, g_col = d_row.reshape(-1)[idx], d_col.reshape(-1)[idx]
        inv = torch.rsqrt(g_row * g_row + g_col * g_col + 1)
        at = lights[image]  # (M, light, xyz)
        lit = [tuple(at[:, i, k] for k in range(3)) for i in range(3)]
        px, py = px[pix % ww], py[pix // ww]
        pressed = self._phong(-g_col * inv, g_row * inv, inv, px, py, depth.reshape(-1)[idx], lit)
        zero = torch.zeros_like(inv)
        flat = self._phong(zero, zero, zero + 1, px, py, zero, lit)
        diff = torch.stack(pressed, 1).sub_(torch.stack(flat, 1))  # (M, light)
        values = torch.einsum("ml,mlc->cm", diff, colours[image])
        dest = (idx - pix) * 3 + pix  # offset of channel 0, as in ``shade_change``
        flat_out = out.view(-1)
        for c in range(3):
            flat_out.index_copy_(0, dest + c * hh * ww, values[c])
        return out.view(n, 3, hh, ww)

    def contact_change(
        self,
        depth: torch.Tensor,
        gel: GelSpec | None = None,
        lights: torch.Tensor | None = None,
        colours: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """What ``render`` adds to the background before its noise (N, 3, S, S), 0-255 scale:
        the shading change times ``diff_scale``, low-passed. With ``lights`` and ``colours``
        (see ``shade_change_lit``) each image is lit by its own lights. Not clamped."""
        gel = gel or GelSpec(size=depth.shape[-1])
        sigma = self._blur_sigma_px(depth, gel)
        out = depth.new_empty(depth.shape[0], 3, *depth.shape[-2:])
        for k in range(0, depth.shape[0], _CHUNK):
            part = depth[k : k + _CHUNK]
            if lights is None or colours is None:
                change = self.shade_change(part, gel)
            else:
                change = self.shade_change_lit(
                    part, gel, lights[k : k + _CHUNK], colours[k : k + _CHUNK]
                )
            out[k : k + _CHUNK] = _gaussian_blur(change.mul_(self.diff_scale), sigma)
        return out

    def _blur_sigma_px(self, depth: torch.Tensor, gel: GelSpec) -> tuple[float, float]:
        """TACTO's low-pass sigma in pixels along (columns, rows) of this image size."""
        return (
            self.blur_sigma_mm * depth.shape[-1] / gel.width_mm,
            self.blur_sigma_mm * depth.shape[-2] / gel.height_mm,
        )

    def skip_random(self, n: int, gel: GelSpec, generator: torch.Generator) -> None:
        """Advance ``generator`` exactly as ``render`` of ``n`` images would, without
        rendering (the noise draws): parts of one stream can then render in parallel."""
        _skip_noise(self, n, (gel.size, gel.size), generator)

    def render(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None,
        gel: GelSpec | None = None,
    ) -> torch.Tensor:
        """Tactile image (N, 3, S, S), float 0-255: background + scaled shading change + noise.

        ``background`` is (3, S, S) or (N, 3, S, S), float or uint8. ``generator`` drives the
        noise; ``None`` renders without noise. ``gel`` defaults to ``GelSpec(size=S)``.
        Images go 16 at a time so the temporaries stay in cache. The noise of each group is
        drawn in turn; torch draws normals in blocks of 16 values, so groups of 16 images
        draw exactly the numbers one draw for the whole batch would.
        """
        size = depth.shape[-1]
        gel = gel or GelSpec(size=size)
        n = depth.shape[0]
        sigma = self._blur_sigma_px(depth, gel)
        image = depth.new_empty(n, 3, *depth.shape[-2:])
        background = background.to(image.dtype)
        noisy = generator is not None and self.noise_std > 0
        for k in range(0, n, _CHUNK):
            change = self.shade_change(depth[k : k + _CHUNK], gel).mul_(self.diff_scale)
            bg = background[k : k + _CHUNK] if background.dim() == 4 else background
            part = _gaussian_blur(change, sigma).add_(bg)
            if noisy:
                noise = torch.randn(part.shape, generator=generator, dtype=part.dtype)
                part.add_(noise.to(part.device).mul_(self.noise_std))
            image[k : k + _CHUNK] = part.clamp_(0, 255)
        return image


def _touched(
    depth: torch.Tensor, gel: GelSpec
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, bool]:
    """Depth gradients (N, H, W) in mm/mm, the flat indices of the pixels whose shading can
    differ from the flat gel's (the pixel or a neighbour pressed), and whether shading all
    pixels densely is cheaper (most are touched; any device but the CPU, where finding the
    touched pixels would wait for the device and a dense batch is one wide kernel) or needed
    (differentiating the depth). The indices are empty when dense."""
    hh, ww = depth.shape[-2:]
    dx, dy = gel.width_mm / ww, gel.height_mm / hh
    d_row, d_col = torch.gradient(depth[:, 0], spacing=(dy, dx), dim=(-2, -1))
    if depth.requires_grad or depth.device.type != "cpu":
        return d_row, d_col, depth.new_empty(0, dtype=torch.int64), True
    active = (depth[:, 0] != 0).logical_or_(d_row != 0).logical_or_(d_col != 0)
    idx = active.view(-1).nonzero().squeeze(1)
    return d_row, d_col, idx, idx.numel() > _DENSE_ABOVE * active.numel()


def _skip_noise(optics: SimOptics, n: int, hw: tuple[int, int], generator: torch.Generator) -> None:
    """Advance ``generator`` as ``optics.render`` of ``n`` images of size ``hw`` would."""
    if optics.noise_std > 0:
        draws = [("randn", (min(_CHUNK, n - k), 3, *hw)) for k in range(0, n, _CHUNK)]
        replay_draws(draws, generator)  # type: ignore[arg-type]


def _pixel_centres(
    hh: int, ww: int, gel: GelSpec, like: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(px (W,), py (H,)) mm of the pixel centres in the sensor frame (rows run towards -y),
    with ``like``'s dtype and device."""
    kw = {"dtype": like.dtype, "device": like.device}
    py = -((torch.arange(hh, **kw) + 0.5) / hh - 0.5) * gel.height_mm
    px = ((torch.arange(ww, **kw) + 0.5) / ww - 0.5) * gel.width_mm
    return px, py


def _power(x: torch.Tensor, exponent: float) -> torch.Tensor:
    """``x ** exponent`` in place; small whole exponents by repeated squaring, not ``pow``."""
    e = float(exponent)
    if not (e.is_integer() and 1 <= e <= 64):
        return x.pow_(e)
    k = int(e)
    result = None
    base = x
    while True:
        if k & 1:
            result = base.clone() if result is None else result.mul_(base)
        k >>= 1
        if not k:
            break
        base = base * base if base is x else base.mul_(base)
    return result


@lru_cache(maxsize=16)
def _flat_shading(
    optics: SimOptics, width_mm: float, height_mm: float, hh: int, ww: int, device: torch.device
) -> torch.Tensor:
    """``optics.shade`` of the undeformed gel (3, H, W) on ``device``; cached, read-only."""
    gel = GelSpec(width_mm, height_mm, ww, 1)
    return optics.shade(torch.zeros(1, 1, hh, ww, device=device), gel)[0]
