"""The no-contact frame (background) of a DIGIT as a smooth low-frequency colour field.

A real DIGIT's no-contact frame is a smooth colour field (reddish upper left, green on the
right, blue-violet lower left) set by where its three LEDs sit and how its gel scatters
their light. We keep it as 6 x 6 cosine (DCT-II) coefficients per channel, so the project
runs without the reference image and the field can be evaluated at any size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch

from tactile_bench.effects import _taxim_fit
from tactile_bench.errors import TactileBenchError

# (channel, k_y, k_x) coefficients of cos(pi k_y (i + .5) / H) cos(pi k_x (j + .5) / W),
# least-squares fit (tactile_bench.sensor.grounding.fit_background_dct) to
# ../shared/real/digit_background_240x320.jpg (TACTO's bg_digit_240_320.jpg, MIT).
# Residual RMSE vs that frame: R 6.8, G 2.3, B 4.0 (0-255); the rest is JPEG texture and
# the sharp rim at the frame edge.
# fmt: off
DIGIT_BACKGROUND_DCT = ((( 99.26,  38.99, -17.47,  -2.86,  -0.94,   0.39),
  ( 28.57,   5.69, -14.17,  -0.50,   0.63,   0.01),
  (-22.59, -19.23,   0.84,   2.42,  -1.55,   0.05),
  (-13.06,  -6.04,   4.86,   2.07,   0.19,  -1.15),
  ( -3.36,  -1.33,  -1.91,   1.25,   0.06,  -2.51),
  ( -0.46,   1.00,  -0.38,  -0.67,  -0.08,   0.41)),

 ((105.20, -11.81,  -8.18,   0.86,  -1.50,  -0.48),
  ( 15.61,   2.53,  -1.38,  -1.30,   0.89,  -0.72),
  (-10.77,   6.43,   5.15,  -0.76,  -0.57,   0.18),
  ( -2.32,   2.99,   0.92,   0.70,  -0.82,  -0.10),
  ( -3.70,  -0.21,   0.35,   0.16,   0.26,   0.24),
  (  0.19,   0.51,   0.03,   0.10,   0.04,   0.20)),

 (( 98.74,  15.55,  -9.90,  -0.79,  -2.05,  -0.24),
  ( 16.76,  -6.19,   4.19,  -0.05,   1.11,  -0.03),
  (  1.69,  -8.77,  -0.14,   0.24,   0.06,  -0.04),
  ( 13.59,   2.29,  -6.56,   0.35,  -2.28,   0.43),
  ( -4.17,  -1.19,   2.11,  -0.29,   0.40,  -0.28),
  (  3.01,  -0.62,   0.11,  -0.02,   0.93,   0.66)))
# fmt: on

#: no-contact field (DCT coefficients) of each sensor whose real frame was measured
BACKGROUND_DCT: dict[str, tuple] = {
    "digit": DIGIT_BACKGROUND_DCT,
    **{name: fit["background_dct"] for name, fit in _taxim_fit.SENSORS.items()},
}
#: (width, height) of each sensor's view of its gel, mm: the DIGIT's 18 x 24 mm portrait view;
#: the GelSights' 640 x 480 frames at Taxim's measured pixmm
GEL_MM: dict[str, tuple[float, float]] = {
    "digit": (18.0, 24.0),
    **{name: tuple(fit["gel_mm"]) for name, fit in _taxim_fit.SENSORS.items()},
}


@dataclass(frozen=True)
class UnitField:
    """How one unit's field differs from its sensor's measured one.

    ``mirror_x`` flips the field left-right (LED ring mounted the other way round),
    ``shift`` moves it by a fraction of the frame (x, y), ``rotation_deg`` turns it about
    the centre, ``gain`` / ``offset`` are per-channel LED intensity and stray light (0-255).
    """

    mirror_x: bool = False
    shift: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sensor: str = "digit"  # the sensor model whose measured field, gel and optics it has


# "digit" is the measured unit. "digit-b" is a plausible second unit (an estimate, not a
# measurement): LED ring mirrored and slightly rotated, bluer/greener LEDs, dimmer red.
UNITS: dict[str, UnitField] = {
    "digit": UnitField(),
    "digit-b": UnitField(
        mirror_x=True,
        shift=(0.05, -0.04),
        rotation_deg=8.0,
        gain=(0.88, 1.06, 1.12),
        offset=(4.0, -2.0, 3.0),
    ),
    **{name: UnitField(sensor=name) for name in _taxim_fit.SENSORS},
}


def _size_hw(size: int | tuple[int, int]) -> tuple[int, int]:
    if isinstance(size, int):
        return size, size
    h, w = size
    return int(h), int(w)


@lru_cache(maxsize=16)
def _field(h: int, w: int, unit: UnitField) -> torch.Tensor:
    coef = torch.tensor(BACKGROUND_DCT[unit.sensor], dtype=torch.float64)  # (3, K, K)
    k = coef.shape[-1]
    y = (torch.arange(h, dtype=torch.float64) + 0.5) / h
    x = (torch.arange(w, dtype=torch.float64) + 0.5) / w
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    # transform about the frame centre, in normalised frame units
    cx, cy = xx - 0.5, yy - 0.5
    a = math.radians(unit.rotation_deg)
    rx = math.cos(a) * cx + math.sin(a) * cy
    ry = -math.sin(a) * cx + math.cos(a) * cy
    if unit.mirror_x:
        rx = -rx
    tx = (rx + 0.5 - unit.shift[0]).clamp(0.0, 1.0)
    ty = (ry + 0.5 - unit.shift[1]).clamp(0.0, 1.0)
    ks = torch.arange(k, dtype=torch.float64)
    by = torch.cos(math.pi * ks[:, None, None] * ty)  # (K, H, W)
    bx = torch.cos(math.pi * ks[:, None, None] * tx)
    field = torch.einsum("cab,ahw,bhw->chw", coef, by, bx)
    gain = torch.tensor(unit.gain, dtype=torch.float64)[:, None, None]
    off = torch.tensor(unit.offset, dtype=torch.float64)[:, None, None]
    return (field * gain + off).clamp(0.0, 255.0)


def digit_background(size: int | tuple[int, int], unit: str = "digit") -> torch.Tensor:
    """No-contact frame of a unit, (3, S, S) (or (3, H, W) for a tuple), 0..255.

    Like the paper, the sensor's frame (the DIGIT's 240 x 320 portrait, a GelSight's
    640 x 480 landscape) is resized to the requested size.
    """
    if unit not in UNITS:
        raise TactileBenchError(f"unknown DIGIT unit {unit!r}; known: {sorted(UNITS)}")
    h, w = _size_hw(size)
    return _field(h, w, UNITS[unit]).float()  # .float() copies: the cache stays intact


def sim_background(size: int | tuple[int, int]) -> torch.Tensor:
    """The simulator's background: TACTO composites onto a real DIGIT frame (the measured one)."""
    return digit_background(size, "digit")
