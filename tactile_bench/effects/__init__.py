"""The catalogue of physical effects a real DIGIT shows and the simple simulator lacks.

``EFFECTS`` is built explicitly here (no registration by import side effect). Its order is
the order of image formation, the one ``SurrogateDigit`` applies them in: by the part they
act on (``IMAGE_FORMATION``: pose -> geometry -> optics -> camera), and within a part as
listed.
"""

from __future__ import annotations

from tactile_bench.effects.base import (
    IMAGE_FORMATION,
    ActsOn,
    Effect,
    EffectContext,
    OpticalScene,
    Param,
    ParamValue,
)
from tactile_bench.effects.camera import (
    CameraNoise,
    DefocusBlur,
    GammaWhiteBalance,
    StreamCompression,
    Vignetting,
)
from tactile_bench.effects.geometry import ElasticSpread, ShearSmear, SurfaceTexture
from tactile_bench.effects.optics import (
    GelWear,
    LedDiffusivity,
    OpticalResponse,
    Shadows,
    UnitBackground,
)
from tactile_bench.effects.pose import PoseError, PressDepthError
from tactile_bench.errors import TactileBenchError

_ORDERED: tuple[Effect, ...] = (
    # pose: where the object really touched
    PoseError(),
    PressDepthError(),
    # geometry: object texture, then the gel's elastic response, then slip
    SurfaceTexture(),
    ElasticSpread(),
    ShearSmear(),
    # optics: this unit's field, the real response, its LEDs, shadows, wear
    UnitBackground(),
    OpticalResponse(),
    LedDiffusivity(),
    Shadows(),
    GelWear(),
    # camera: lens, sensor, image processor, stream
    DefocusBlur(),
    Vignetting(),
    CameraNoise(),
    GammaWhiteBalance(),
    StreamCompression(),
)

EFFECTS: dict[str, Effect] = {e.name: e for e in _ORDERED}
EFFECT_ORDER: tuple[str, ...] = tuple(EFFECTS)


def get_effect(name: str) -> Effect:
    """The registered effect called ``name``; a one-line error listing the known ones."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise TactileBenchError(
            f"unknown effect {name!r}; known: {', '.join(EFFECT_ORDER)}"
        ) from None


def effects_in(acts_on: ActsOn) -> tuple[Effect, ...]:
    """Registered effects acting on one part of image formation, in application order."""
    return tuple(e for e in _ORDERED if e.acts_on == acts_on)


__all__ = [
    "EFFECTS",
    "EFFECT_ORDER",
    "IMAGE_FORMATION",
    "ActsOn",
    "Effect",
    "EffectContext",
    "OpticalScene",
    "Param",
    "ParamValue",
    "effects_in",
    "get_effect",
]
