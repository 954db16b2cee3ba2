"""Write a surrogate profile: what a calibration of a user's own sensor hands back.

``write_profile`` writes the YAML ``SurrogateDigit.from_profile`` reads: name, unit,
description, effects and, for a sensor of the user's own, its ``sensor:`` block (gel view,
no-contact field, optical response, LED azimuths; ``effects.sensors``). The text is
checked by loading it as ``from_profile`` would before anything is written, then written
atomically, so a bad profile never reaches the disk and a killed write leaves none.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from tactile_bench.effects.sensors import SensorFit
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.safe_yaml import MAX_BYTES, load_yaml_text
from tactile_bench.io import atomic_write_text
from tactile_bench.sensor.surrogate import SurrogateDigit

PROFILE_SUFFIXES = (".yaml", ".yml")
_HEADER = "# A surrogate profile (tactile_bench.sensor.profile_io.write_profile).\n"


def _plain(value: Any, where: str) -> Any:
    """A parameter value as YAML can hold it: a number, or a list of them."""
    if hasattr(value, "tolist"):  # a tensor or numpy value
        value = value.tolist()
    if isinstance(value, bool) or not isinstance(value, (int, float, list, tuple)):
        raise TactileBenchError(f"{where}: must be a number, got {type(value).__name__}")
    if isinstance(value, (list, tuple)):
        return [_plain(v, where) for v in value]
    return value if isinstance(value, int) else float(value)


def _effects(effects: Mapping[str, Mapping[str, Any] | None], where: str) -> dict[str, dict]:
    if not isinstance(effects, Mapping):
        raise TactileBenchError(f"{where}: effects: must be a mapping of effect name to params")
    out: dict[str, dict] = {}
    for name, params in effects.items():
        if params is not None and not isinstance(params, Mapping):
            raise TactileBenchError(f"{where}: effects.{name}: must be a mapping of params")
        out[str(name)] = {
            str(k): _plain(v, f"{where}: effects.{name}.{k}") for k, v in (params or {}).items()
        }
    return out


def profile_text(
    *,
    name: str,
    description: str,
    effects: Mapping[str, Mapping[str, Any] | None],
    sensor: Mapping[str, Any] | SensorFit | None,
    unit: str | None = None,
    where: str = "profile",
) -> str:
    """The YAML of a profile (what ``write_profile`` writes), checked as ``from_profile``
    would read it; errors start with ``where``."""
    data: dict[str, Any] = {"name": str(name)}
    if sensor is None:
        data["unit"] = unit or "digit"
    else:
        if isinstance(sensor, SensorFit):
            fit, unit = sensor, unit or sensor.name
        else:
            unit = unit or str(name)
            fit = SensorFit.from_mapping(unit, sensor, where)
        data["unit"] = unit
    data["description"] = str(description)
    data["effects"] = _effects(effects, where)
    if sensor is not None:
        data["sensor"] = fit.to_dict()
    text = _HEADER + yaml.safe_dump(
        data, sort_keys=False, default_flow_style=None, width=100, allow_unicode=True
    )
    if len(text.encode()) > MAX_BYTES:
        raise TactileBenchError(f"{where}: the profile would exceed {MAX_BYTES} bytes")
    SurrogateDigit.from_mapping(load_yaml_text(text, where), where, str(name))
    return text


def write_profile(
    path: str | Path,
    *,
    name: str,
    description: str,
    effects: Mapping[str, Mapping[str, Any] | None],
    sensor: Mapping[str, Any] | SensorFit | None,
    unit: str | None = None,
) -> Path:
    """Write a profile YAML that ``SurrogateDigit.from_profile(path)`` loads; returns ``path``.

    ``effects``: effect name -> params (``{}`` for an effect's defaults), as in the built-in
    profiles. ``sensor``: None for a built-in sensor (``unit``, default ``digit``), or the
    user's own sensor: a ``SensorFit`` or a mapping {gel_mm: [w, h], background_dct:
    (3, K, K), response_weights: (22, 3, 6), led_azimuth_deg: [r, g, b]} (lists, arrays or
    tensors); its unit is then ``unit`` or ``name``. Refused in one line before writing if
    it would not load; written atomically.
    """
    path = Path(path)
    if path.suffix.lower() not in PROFILE_SUFFIXES:
        raise TactileBenchError(f"{path}: a profile file ends in .yaml (or .yml)")
    if path.is_dir():
        raise TactileBenchError(f"{path}: is a folder; give the profile's file path")
    text = profile_text(
        name=name,
        description=description,
        effects=effects,
        sensor=sensor,
        unit=unit,
        where=str(path),
    )
    return atomic_write_text(path, text)
