"""Each sensor model's fitted numbers, by key: the built-in sensors and any a profile brings.

A sensor fit is what renders of a sensor need beyond its effects' parameters: the view of
its gel (mm), its no-contact field (cosine coefficients), the compact optical response's
weights and its LEDs' azimuths. The built-ins (``digit``, ``gelsight``, ``gelsight-mini``)
are registered under their names. A fit a profile carries (a user's own calibration, the
profile's ``sensor:`` block) is registered under ``<name>@<content hash>``, so two
calibrations of one name never collide in a process and a key always stands for the same
numbers: caches keyed by it (``sensor.background``, ``effects.optics``) are never stale.
A spawned worker gets a fit with the ``SurrogateDigit`` that carries it, which registers
it again when unpickled.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import torch

from tactile_bench.effects._optics_fit import (
    DIGIT_BACKGROUND_DCT,
    LED_AZIMUTH_DEG,
    N_HARM,
    N_MAG,
    RESPONSE_WEIGHTS,
)
from tactile_bench.effects._taxim_fit import SENSORS as TAXIM_FITS
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import json_sha256

#: the keys of a profile's ``sensor:`` block, in the order they are written
SENSOR_KEYS = ("gel_mm", "background_dct", "response_weights", "led_azimuth_deg")
#: features of the compact optical response: the contact offset, then slope-angle powers
#: times direction harmonics (``effects.optics.response_features``)
N_FEATURES = 1 + N_MAG * (1 + 2 * N_HARM)
MAX_DCT_TERMS = 64  # cosine terms per axis of a no-contact field (the built-ins have 6-8)
MAX_GEL_MM = 500.0
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_SHAPES = {
    "gel_mm": "2 numbers [width, height] in mm",
    "background_dct": "3 x K x K numbers (K cosine terms per axis, 1..64)",
    "response_weights": f"{N_FEATURES} x 3 x 6 numbers (feature, channel, position term)",
    "led_azimuth_deg": "3 numbers [r, g, b] in degrees",
}


def _nested(value: Any, depth: int = 0) -> tuple[list[float], tuple[int, ...]] | None:
    """(flat numbers, shape) of a rectangular nest of lists of numbers (at most 3 deep),
    else None."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [float(value)], ()
    if not isinstance(value, (list, tuple)) or not value or depth >= 3:
        return None
    flat: list[float] = []
    shapes = set()
    for item in value:
        part = _nested(item, depth + 1)
        if part is None:
            return None
        flat += part[0]
        shapes.add(part[1])
    if len(shapes) != 1:  # ragged
        return None
    return flat, (len(value), *shapes.pop())


_SHAPE_OK: dict[str, Callable[[tuple[int, ...]], bool]] = {
    "gel_mm": lambda s: s == (2,),
    "background_dct": lambda s: len(s) == 3 and s[0] == 3 and s[1] == s[2] <= MAX_DCT_TERMS,
    "response_weights": lambda s: s == (N_FEATURES, 3, 6),
    "led_azimuth_deg": lambda s: s == (3,),
}


def _array(key: str, value: Any, where: str) -> np.ndarray:
    """``value`` (lists, a numpy array or a tensor) as a float64 array of its key's shape,
    finite; anything else is one line naming ``where`` and the key."""
    if hasattr(value, "tolist"):  # a tensor or an array from a fitting script
        value = value.tolist()
    found = _nested(value)
    shape = None if found is None else found[1]
    ok = shape is not None and _SHAPE_OK[key](shape)
    if not ok:
        got = f"shape {shape}" if shape is not None else "not a nest of lists of numbers"
        raise TactileBenchError(f"{where}: sensor.{key}: must be {_SHAPES[key]}; got {got}")
    array = np.asarray(found[0], dtype=np.float64).reshape(shape)
    if not np.isfinite(array).all():
        raise TactileBenchError(f"{where}: sensor.{key}: must be finite numbers (no inf, nan)")
    if key == "gel_mm" and not ((array > 0) & (array <= MAX_GEL_MM)).all():
        raise TactileBenchError(
            f"{where}: sensor.gel_mm: width and height must be in (0, {MAX_GEL_MM:g}] mm"
        )
    return array


def check_sensor_name(name: Any, where: str, key: str = "unit") -> str:
    """A sensor's name: letters, digits, ``.``, ``_``, ``-`` (it becomes part of its key)."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise TactileBenchError(
            f"{where}: {key}: {name!r} is not a sensor name (1-64 letters, digits, '.', '_', "
            "'-', starting with a letter or digit)"
        )
    return name


@dataclass(frozen=True, eq=False)
class SensorFit:
    """One sensor model's fitted numbers (checked and converted on construction).

    ``background_dct`` (3, K, K) float64 and ``response_weights`` (F, 3, 6) float32 are
    shared by every render of the sensor: never modify them in place.
    """

    name: str
    gel_mm: tuple[float, float]
    background_dct: torch.Tensor
    response_weights: torch.Tensor
    led_azimuth_deg: tuple[float, float, float]

    def __post_init__(self) -> None:
        where = f"sensor {self.name!r}"
        check_sensor_name(self.name, where, "name")
        arrays = {k: _array(k, getattr(self, k), where) for k in SENSOR_KEYS}
        set_ = object.__setattr__  # frozen: the converted values are set once, here
        set_(self, "gel_mm", tuple(float(v) for v in arrays["gel_mm"]))
        set_(self, "led_azimuth_deg", tuple(float(v) for v in arrays["led_azimuth_deg"]))
        set_(self, "background_dct", torch.tensor(arrays["background_dct"], dtype=torch.float64))
        weights = torch.tensor(arrays["response_weights"], dtype=torch.float32)
        set_(self, "response_weights", weights)

    @classmethod
    def from_mapping(cls, name: str, data: Any, where: str) -> SensorFit:
        """A profile's ``sensor:`` block; an unknown, missing or malformed key is one line
        naming ``where`` (the file) and the key."""
        if not isinstance(data, Mapping):
            raise TactileBenchError(
                f"{where}: sensor: must be a mapping with keys {', '.join(SENSOR_KEYS)}"
            )
        for key in data:
            if key not in SENSOR_KEYS:
                raise TactileBenchError(
                    f"{where}: sensor.{key}: unknown key; known: {', '.join(SENSOR_KEYS)}"
                )
        for key in SENSOR_KEYS:
            if key not in data:
                raise TactileBenchError(f"{where}: sensor.{key}: missing ({_SHAPES[key]})")
        check_sensor_name(name, where)
        values = {k: _array(k, data[k], where) for k in SENSOR_KEYS}
        return cls(name, **values)

    def to_dict(self) -> dict[str, list]:
        """The ``sensor:`` block of a profile: plain lists that load back to equal numbers
        (the weights at float32's shortest exact form)."""
        weights = [
            [[float(str(np.float32(v))) for v in row] for row in plane]
            for plane in self.response_weights.tolist()
        ]
        return {
            "gel_mm": list(self.gel_mm),
            "background_dct": self.background_dct.tolist(),
            "response_weights": weights,
            "led_azimuth_deg": list(self.led_azimuth_deg),
        }

    @cached_property
    def digest(self) -> str:
        """sha256 of the name and the numbers as the renders use them."""
        return json_sha256({"name": self.name, **self.to_dict()})

    @property
    def key(self) -> str:
        """The registry key of this fit as a profile's sensor: ``<name>@<hash>``."""
        return f"{self.name}@{self.digest[:16]}"


_REGISTRY: dict[str, SensorFit] = {}


def register_sensor(fit: SensorFit) -> str:
    """Register a profile's sensor fit; returns its key (``<name>@<content hash>``).

    Registering the same numbers again is free and returns the same key."""
    if not isinstance(fit, SensorFit):
        raise TactileBenchError(f"register_sensor: expected a SensorFit, got {type(fit).__name__}")
    key = fit.key
    _REGISTRY.setdefault(key, fit)
    return key


def sensor_fit(key: str) -> SensorFit:
    """The fit registered under ``key``; an unknown key is an error naming the known ones."""
    fit = _REGISTRY.get(key)
    if fit is None:
        raise TactileBenchError(
            f"unknown sensor {key!r}; known: {known_sensors()} (a profile's own sensor is "
            "known once its profile is loaded in this process)"
        )
    return fit


def is_sensor(key: str) -> bool:
    """Whether ``key`` names a registered sensor fit."""
    return key in _REGISTRY


def known_sensors() -> list[str]:
    """Registered keys, built-ins first."""
    return [*BUILTIN_SENSORS, *sorted(k for k in _REGISTRY if k not in BUILTIN_SENSORS)]


def _builtin(name: str, fit: Mapping[str, Any]) -> SensorFit:
    return SensorFit(
        name,
        tuple(fit["gel_mm"]),
        fit["background_dct"],
        fit["response_weights"],
        tuple(fit["led_azimuth_deg"]),
    )


_BUILTIN_FITS = {
    "digit": {
        "gel_mm": (18.0, 24.0),  # the DIGIT's 240 x 320 portrait view
        "background_dct": DIGIT_BACKGROUND_DCT,
        "response_weights": RESPONSE_WEIGHTS,
        "led_azimuth_deg": LED_AZIMUTH_DEG,
    },
    **TAXIM_FITS,  # the GelSights' 640 x 480 frames at Taxim's measured pixmm
}
#: the sensors shipped with the package, registered under their plain names
BUILTIN_SENSORS: tuple[str, ...] = tuple(_BUILTIN_FITS)
for _name, _fit in _BUILTIN_FITS.items():
    _REGISTRY[_name] = _builtin(_name, _fit)
