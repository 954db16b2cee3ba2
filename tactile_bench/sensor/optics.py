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

import torch
import torch.nn.functional as F

from tactile_bench.sensor.depth import GelSpec


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
        v the directions from the surface point to the light and to the camera.
        """
        _, _, hh, ww = depth.shape
        nx, ny, nz = _normal_components(depth, gel)  # each (N, H, W)
        py = (-((torch.arange(hh, dtype=depth.dtype) + 0.5) / hh - 0.5) * gel.height_mm)[:, None]
        px = ((torch.arange(ww, dtype=depth.dtype) + 0.5) / ww - 0.5) * gel.width_mm
        pz = depth[:, 0]
        vx, vy, vz = -px, -py, self.camera_distance_mm - pz
        inv = torch.rsqrt(vx * vx + vy * vy + vz * vz)
        vx, vy, vz = vx * inv, vy * inv, vz * inv
        channels = []
        for lx, ly, lz in self.light_positions().tolist():
            ax, ay, az = lx - px, ly - py, lz - pz
            inv = torch.rsqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax * inv, ay * inv, az * inv
            n_dot_l = nx * ax + ny * ay + nz * az
            # reflection r = 2 (n.l) n - l, so r.v = 2 (n.l)(n.v) - l.v
            n_dot_v = nx * vx + ny * vy + nz * vz
            r_dot_v = (2 * n_dot_l * n_dot_v - (ax * vx + ay * vy + az * vz)).clamp_(min=0)
            spec = r_dot_v.pow_(self.shininess).mul_(n_dot_l > 0)
            channels.append(
                n_dot_l.clamp_(min=0).mul_(self.diffuse).add_(spec, alpha=self.specular)
            )
        return torch.stack(channels, 1).add_(self.ambient).mul_(self.intensity)

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
        """
        size = depth.shape[-1]
        gel = gel or GelSpec(size=size)
        flat = self.shade(torch.zeros_like(depth[:1]), gel)
        sigma = (
            self.blur_sigma_mm * size / gel.width_mm,
            self.blur_sigma_mm * depth.shape[-2] / gel.height_mm,
        )
        # shade in small chunks: the ~30 temporaries per chunk then stay in cache (~1.3x faster)
        parts = [
            _gaussian_blur((self.shade(part, gel) - flat) * self.diff_scale, sigma)
            for part in depth.split(64)
        ]
        diff = torch.cat(parts) if parts else depth.new_zeros(0, 3, *depth.shape[-2:])
        image = diff + background.to(diff.dtype)
        if generator is not None and self.noise_std > 0:
            noise = torch.randn(image.shape, generator=generator, dtype=image.dtype)
            image = image + self.noise_std * noise
        return image.clamp_(0, 255)
