"""The no-contact frame (background) of a DIGIT as a smooth low-frequency colour field.

A real DIGIT's no-contact frame is a smooth colour field (reddish upper left, green on the
right, blue-violet lower left) set by where its three LEDs sit and how its gel scatters
their light. We keep it as 6 x 6 cosine (DCT-II) coefficients per channel, so the project
runs without the reference image and the field can be evaluated at any size. Each sensor's
coefficients (the DIGIT's, the GelSights', a profile's own sensor's) and its gel view are
read from the sensor registry (``effects.sensors``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch

from tactile_bench.effects.sensors import BUILTIN_SENSORS, is_sensor, sensor_fit
from tactile_bench.errors import TactileBenchError


def gel_mm(sensor: str) -> tuple[float, float]:
    """(width, height) of a sensor's view of its gel, mm: the DIGIT's 18 x 24 mm portrait
    view, the GelSights' 640 x 480 frames at Taxim's measured pixmm, a profile's own."""
    return sensor_fit(sensor).gel_mm


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
    **{name: UnitField(sensor=name) for name in BUILTIN_SENSORS if name != "digit"},
}


def unit_field(unit: str) -> UnitField:
    """A unit's field: a built-in unit's, or (for a profile's own sensor, its registry key)
    the sensor's measured field as it is."""
    if unit in UNITS:
        return UNITS[unit]
    if is_sensor(unit):
        return UnitField(sensor=unit)
    raise TactileBenchError(f"unknown DIGIT unit {unit!r}; known: {sorted(UNITS)}")


def _size_hw(size: int | tuple[int, int]) -> tuple[int, int]:
    if isinstance(size, int):
        return size, size
    h, w = size
    return int(h), int(w)


@lru_cache(maxsize=16)
def _field(h: int, w: int, unit: UnitField) -> torch.Tensor:
    # a key stands for one set of numbers (effects.sensors): this cache is never stale
    coef = sensor_fit(unit.sensor).background_dct  # (3, K, K) float64
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
    field = unit_field(unit)
    h, w = _size_hw(size)
    return _field(h, w, field).float()  # .float() copies: the cache stays intact


def sim_background(size: int | tuple[int, int]) -> torch.Tensor:
    """The simulator's background: TACTO composites onto a real DIGIT frame (the measured one)."""
    return digit_background(size, "digit")
