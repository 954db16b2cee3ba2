"""The ``profile`` translator: a sensor profile's own rendering, nothing learned.

A profile (``sensor/profiles/*.yaml`` format: the effects of image formation and their
parameters) renders a depth as that sensor would (``SurrogateDigit.render_surface``). This
translator puts that rendering on the caller's no-contact frame: the profile's image minus
the profile's own no-contact frame, plus the given one (``foreground_to_image``: clamped to
0..255), as ``real_presses`` composes its "calibrated sim" row. So a profile calibrated from
a sensor's fitting pairs (``calibrate``) is scored on the held-out pairs beside the learned
translators (``compare_translators``), on the same real frames.

``profile`` is a YAML path. In a recipe (``fit_translator`` or ``translate``) a relative
path is read from the recipe's folder, as every path there; used directly
(``create_translator``) from the working directory. A built-in profile name is refused: the
built-ins are what plays "real" in this project, so rendering one would hand the surrogate's
hidden parameters to a translator (an oracle, not a model fitted from data).

The gel view the depth covers is the profile unit's (a DIGIT's 18 x 24 mm), or ``gel_mm``
(the data's gel.json, e.g. a ``paired_data`` stage's metrics). Nothing to fit: ``fit_pairs``
returns None, like ``sim``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import torch
from pydantic import Field, field_validator

from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.translators.base import Translator, image_to_foreground
from tactile_bench.translators.sim import SimConfig

MAX_GEL_MM = 500.0


def _load(profile: str) -> SurrogateDigit:
    if not Path(profile).suffix:
        raise TactileBenchError(
            f"profile: {profile!r} is a built-in surrogate profile (what plays 'real' here); "
            "give a profile YAML path, e.g. the profile.yaml that calibrate wrote"
        )
    return SurrogateDigit.from_profile(profile)


class ProfileConfig(SimConfig):
    """Which profile renders, over which gel view (``seed``: its random effects' draws when
    no generator is given; ``max_steps`` is ignored)."""

    profile: str = Field(
        description="a sensor profile YAML path (e.g. the one calibrate wrote; relative to "
        "the recipe in a recipe); built-in names are refused"
    )
    gel_mm: tuple[float, float] | None = Field(
        default=None,
        description="(width, height) mm of the gel view the depth covers; None: the "
        "profile unit's (a DIGIT's 18 x 24)",
    )

    @field_validator("profile")
    @classmethod
    def _loads(cls, value: str) -> str:
        try:
            _load(value)
        except TactileBenchError as exc:
            raise ValueError(str(exc)) from None
        return value

    @field_validator("gel_mm")
    @classmethod
    def _view(cls, value: tuple[float, float] | None) -> tuple[float, float] | None:
        if value is not None and not all(0 < v <= MAX_GEL_MM for v in value):
            raise ValueError(f"width and height must be in (0, {MAX_GEL_MM:g}] mm")
        return value


class ProfileTranslator(Translator):
    """Depth -> the profile's image, on the caller's no-contact frame. Not trainable."""

    name = "profile"
    Config = ProfileConfig
    trainable = False
    #: config keys that name files: a recipe's stages read them from the recipe's folder
    path_keys: ClassVar[tuple[str, ...]] = ("profile",)

    def __init__(self, config: ProfileConfig | dict | None = None) -> None:
        super().__init__(config)
        self.sensor = _load(self.config.profile)
        self._frames: dict[tuple[int, str], torch.Tensor] = {}

    def _gel(self, size: int) -> GelSpec:
        if self.config.gel_mm is None:
            return self.sensor.gel(size, oversample=1)
        return GelSpec(*self.config.gel_mm, size, 1)

    def _frame(self, gel: GelSpec, device: torch.device) -> torch.Tensor:
        """The profile's no-contact frame at this size (rendered once a size and device)."""
        key = (gel.size, str(device))
        if key not in self._frames:
            self._frames[key] = self.sensor.background(gel).to(device)
        return self._frames[key]

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        gel = self._gel(depth.shape[-1])
        if generator is None:
            generator = torch.Generator().manual_seed(self.config.seed)
        image = self.sensor.render_surface(depth.float(), gel, generator)
        return image_to_foreground(image, self._frame(gel, image.device))

    def fit_diagnostics(self) -> dict[str, Any]:
        """Which profile rendered, with which effects."""
        return {"profile": self.sensor.name, "effects": self.sensor.effects_enabled}
