"""The surrogate DIGIT: the "real" sensor of this project, built from named physical effects.

No real sensor is at hand, so real data come from this model. It starts from the same contact
geometry as the simulator and adds, step by step, the effects a real DIGIT shows and the
simple simulator lacks (``tactile_bench.effects``). The order of the steps is part of the
model and follows image formation (the effects of a step are those that act on it,
``Effect.acts_on``):

1. **pose** (on ``Poses``): the real contact differs from the commanded one;
2. ``render_height``: rigid signed height of the object at ``size * oversample``;
3. **geometry** (on the signed height, at that resolution): object texture, elastic spread
   of the gel, slip;
4. the gel surface is the positive part (displacement towards the camera, mm),
   area-averaged to ``size`` (the paper resizes 320 x 240 frames to 64 x 64; the simulator
   shades at ``size`` too, so the two differ in physics, not in resolution);
5. **optics** (on an ``OpticalScene`` at ``size``): the scene starts as the
   simulator's noise-free rendering (``SimOptics``: three ideal lights, Phong, TACTO's
   0.5 scale and low-pass) over this unit's no-contact field; the
   effects swap in the real response fitted from Taxim's calibration, the unit's LEDs,
   shadows, wear; the sensor saturates at 0..255;
6. **camera** (on the image): defocus, vignetting, Poisson-Gaussian noise, gamma and white
   balance, JPEG stream compression; clamp to 0..255.

With every effect switched off the surrogate is a noise-free TACTO-like simulator over the
measured background, so ``without(name)`` measures how much of the sim-to-real gap an
effect carries. Its parameters live only here and in ``profiles/``: models never see them.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from tactile_bench.effects import EFFECT_ORDER, EFFECTS, get_effect
from tactile_bench.effects.base import ActsOn, EffectContext, ParamValue
from tactile_bench.effects.draws import replay_draws
from tactile_bench.effects.kernels import area_pool
from tactile_bench.effects.optics import new_scene
from tactile_bench.effects.sensors import SensorFit, check_sensor_name, register_sensor
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.contacts import Poses
from tactile_bench.guard.safe_yaml import load_yaml_file
from tactile_bench.sensor.background import UNITS, digit_background, gel_mm, unit_field
from tactile_bench.sensor.depth import GelSpec, render_height
from tactile_bench.sensor.heightfield import HeightFieldBank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import timed_span

PROFILE_DIR = Path(__file__).with_name("profiles")
NO_CONTACT_MM = 1.0  # object distance from the gel for the no-contact frame
_PROFILE_KEYS = {"name", "unit", "description", "effects", "sensor"}


def available_profiles() -> list[str]:
    """Names of the built-in profiles (``sensor/profiles/*.yaml``)."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def _check_effects(
    effects: Mapping[str, Mapping[str, Any] | None], where: str
) -> dict[str, dict[str, ParamValue]]:
    out: dict[str, dict[str, ParamValue]] = {}
    if not isinstance(effects, Mapping):
        raise TactileBenchError(f"{where}: effects: must be a mapping of effect name to params")
    for name, params in effects.items():
        if name not in EFFECTS:
            raise TactileBenchError(
                f"{where}: effects.{name}: unknown effect; known: {', '.join(EFFECT_ORDER)}"
            )
        params = {} if params is None else params
        if not isinstance(params, Mapping):
            raise TactileBenchError(f"{where}: effects.{name}: must be a mapping of params")
        effect = EFFECTS[name]
        for key, value in params.items():
            try:
                effect.validate({key: value})
            except TactileBenchError as err:
                raise TactileBenchError(f"{where}: effects.{name}.{key}: {err}") from None
        out[name] = dict(params)
    return out


def _resize(x: torch.Tensor, size: int) -> torch.Tensor:
    """Area-average down (or bilinear up) to size x size, like a camera pixel integrates."""
    if tuple(x.shape[-2:]) == (size, size):
        return x
    h, w = x.shape[-2:]
    if h == w and h % size == 0:  # the oversampled render: same sums as the adaptive pool
        return area_pool(x, h // size)
    if x.shape[-1] >= size and x.shape[-2] >= size:
        return F.adaptive_avg_pool2d(x, (size, size))
    return F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)


class SurrogateDigit:
    """A surrogate DIGIT unit: a background field and an ordered set of effects with params."""

    def __init__(
        self,
        effects: Mapping[str, Mapping[str, ParamValue] | None] | None = None,
        unit: str = "digit",
        name: str = "custom",
        description: str = "",
        source: str = "<code>",
        sensor_fit: SensorFit | None = None,
    ) -> None:
        if sensor_fit is not None:  # a profile's own sensor: the unit is its registry key
            if unit not in (sensor_fit.name, sensor_fit.key):
                raise TactileBenchError(
                    f"{source}: unit: {unit!r} must name the profile's sensor ({sensor_fit.name!r})"
                )
            unit = register_sensor(sensor_fit)
        elif unit not in UNITS:
            raise TactileBenchError(f"{source}: unit: unknown {unit!r}; known: {sorted(UNITS)}")
        self.unit = unit
        self.name = name
        self.description = description
        self.source = source
        self.sensor_fit = sensor_fit
        self._effects = _check_effects(effects or {}, source)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled (a spawned worker): its own sensor is registered in this process too."""
        self.__dict__.update(state)
        if self.sensor_fit is not None:
            register_sensor(self.sensor_fit)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_profile(cls, name_or_path: str | Path = "digit") -> SurrogateDigit:
        """Load ``sensor/profiles/<name>.yaml`` or a YAML file path."""
        path = Path(name_or_path)
        if not path.suffix:
            path = PROFILE_DIR / f"{name_or_path}.yaml"
        if not path.exists():
            raise TactileBenchError(
                f"{path}: no such surrogate profile; built-in: {available_profiles()}"
            )
        data = load_yaml_file(path, "profile")  # regular file, bounded aliases, no dup keys
        return cls.from_mapping(data, str(path), path.stem)

    @classmethod
    def from_mapping(cls, data: Any, source: str, default_name: str = "custom") -> SurrogateDigit:
        """A profile's parsed YAML; errors name ``source`` (the file) and the key.

        With a ``sensor:`` block (a sensor fit: ``effects.sensors.SensorFit.from_mapping``),
        ``unit`` names that sensor (default: the profile's name)."""
        if not isinstance(data, Mapping):
            raise TactileBenchError(
                f"{source}: must be a mapping with keys {sorted(_PROFILE_KEYS)}"
            )
        extra = set(data) - _PROFILE_KEYS
        if extra:
            raise TactileBenchError(f"{source}: {sorted(extra)[0]}: unknown key")
        name = str(data.get("name", default_name))
        fit = None
        if "sensor" in data:  # its name is the unit's (or, without one, the profile's)
            unit = check_sensor_name(
                data.get("unit", name), source, "unit" if "unit" in data else "name"
            )
            fit = SensorFit.from_mapping(unit, data["sensor"], source)
        return cls(
            effects=data.get("effects") or {},
            unit=str(data.get("unit", name if fit is not None else "digit")),
            name=name,
            description=str(data.get("description", "")),
            source=source,
            sensor_fit=fit,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain, YAML-able description (for recipe hashes and reports)."""
        effects = {
            n: {
                k: float(v) if not isinstance(v, torch.Tensor) else v.tolist() for k, v in p.items()
            }
            for n, p in self._effects.items()
        }
        return {"name": self.name, "unit": self.unit, "effects": effects}

    def __repr__(self) -> str:
        on = self.effects_enabled
        return f"SurrogateDigit(name={self.name!r}, unit={self.unit!r}, effects={on})"

    @property
    def sensor(self) -> str:
        """The sensor model of this unit (``digit``, ``gelsight``, ``gelsight-mini``, or a
        profile's own sensor's registry key ``<name>@<hash>``)."""
        return unit_field(self.unit).sensor

    def gel(self, size: int = 64, oversample: int = 2) -> GelSpec:
        """This sensor's view of its gel at ``size`` x ``size`` (the DIGIT's 18 x 24 mm, ...)."""
        width, height = gel_mm(self.sensor)
        return GelSpec(width, height, size, oversample)

    # ------------------------------------------------------------------ effect switches
    @property
    def effects_enabled(self) -> list[str]:
        """Enabled effects in application order."""
        return [n for n in EFFECT_ORDER if n in self._effects]

    def params(self, name: str) -> dict[str, ParamValue]:
        """Full parameter set of an enabled effect (profile values over defaults)."""
        if name not in self._effects:
            raise TactileBenchError(f"surrogate {self.name!r}: effect {name!r} is not enabled")
        return get_effect(name).validate(self._effects[name])

    def _copy(self, effects: Mapping[str, Mapping[str, ParamValue]], suffix: str) -> SurrogateDigit:
        return SurrogateDigit(
            effects,
            self.unit,
            f"{self.name}{suffix}",
            self.description,
            self.source,
            self.sensor_fit,
        )

    def without(self, *names: str) -> SurrogateDigit:
        """A copy with the named effects switched off (unknown names are an error)."""
        for n in names:
            get_effect(n)
        kept = {n: p for n, p in self._effects.items() if n not in names}
        return self._copy(kept, "".join(f"-{n}" for n in names))

    def only(self, *names: str) -> SurrogateDigit:
        """A copy with only the named effects on (at this unit's params or defaults)."""
        for n in names:
            get_effect(n)
        return self._copy({n: self._effects.get(n, {}) for n in names}, "-only")

    def with_params(self, name: str, **values: ParamValue) -> SurrogateDigit:
        """A copy with one effect's params updated (the effect is switched on if it was off)."""
        get_effect(name)
        effects = dict(self._effects)
        effects[name] = {**effects.get(name, {}), **values}
        return self._copy(effects, "")

    # ------------------------------------------------------------------ rendering
    def _apply_effects_on(
        self, acts_on: ActsOn, x: Any, generator: torch.Generator | None, ctx: EffectContext
    ) -> Any:
        for n in self.effects_enabled:
            effect = EFFECTS[n]
            if effect.acts_on == acts_on:
                with timed_span(f"real.{acts_on}.{n}"):
                    x = effect.apply(x, self._effects[n], generator, ctx)
        return x

    def render_surface(
        self,
        height: torch.Tensor,
        gel: GelSpec | None = None,
        generator: torch.Generator | None = None,
        yaw_deg: torch.Tensor | None = None,
        stochastic: bool = True,
    ) -> torch.Tensor:
        """Image (N, 3, S, S) 0..255 from a signed height or depth map (N, 1, H, W), mm.

        Entry point for callers without a braille bank (pretraining objects, a depth image
        from elsewhere): steps 3-6 of the model. Any H, W works; ``gel.size`` sets S.
        """
        gel = gel or self.gel()
        if height.dim() != 4 or height.shape[1] != 1:
            raise TactileBenchError(
                f"render_surface: height must be (N, 1, H, W), got {tuple(height.shape)}"
            )
        ctx = EffectContext(gel.width_mm, gel.height_mm, stochastic, yaw_deg, self.sensor)
        h = self._apply_effects_on("geometry", height.float(), generator, ctx)
        with timed_span("real.resize"):
            surface = _resize(h.clamp(min=0.0), gel.size)
        bg = digit_background(gel.size, self.unit).to(surface.device)
        # skipped when optical_response replaces it outright (it would be multiplied by 0)
        with timed_span("real.sim_shading"):
            delta = None if self._sim_shading_replaced() else self._sim_delta(surface, bg, gel)
            scene = new_scene(surface, bg, delta)
        scene = self._apply_effects_on("optics", scene, generator, ctx)
        with timed_span("real.composite"):
            image = scene.composite()
        if image.shape[0] != surface.shape[0]:
            image = image.expand(surface.shape[0], -1, -1, -1)
        image = self._apply_effects_on("camera", image, generator, ctx)
        return image.clamp(0.0, 255.0)

    render_depth_image = render_surface

    def _sim_shading_replaced(self) -> bool:
        """True when optical_response is on at blend 1 and not being fitted."""
        if "optical_response" not in self._effects:
            return False
        blend = self.params("optical_response")["blend"]
        if isinstance(blend, torch.Tensor):
            return not blend.requires_grad and bool((blend == 1).all())
        return float(blend) == 1.0

    @staticmethod
    def _sim_delta(surface: torch.Tensor, background: torch.Tensor, gel: GelSpec) -> torch.Tensor:
        """The simulator's noise-free colour change over ``background``: the base scene.

        With every effect off the surrogate therefore renders exactly what ``SimOptics``
        renders without noise on this unit's background.
        """
        res = GelSpec(gel.width_mm, gel.height_mm, surface.shape[-1], 1)
        return SimOptics().render(surface, background, None, res) - background

    def background(self, size: int | GelSpec = 64) -> torch.Tensor:
        """This unit's no-contact frame (3, S, S), 0..255: no per-frame noise or slip.

        Rendered through the same steps with nothing within ``NO_CONTACT_MM`` of the gel,
        so per-unit effects (background, LEDs, wear, lens, tone curve, JPEG) show in it.
        """
        gel = size if isinstance(size, GelSpec) else self.gel(int(size))
        n = gel.size * gel.oversample
        flat = torch.full((1, 1, n, n), -NO_CONTACT_MM)
        return self.render_surface(flat, gel, None, stochastic=False)[0]

    #: contacts per pass of ``render``; its random draws go chunk by chunk
    RENDER_CHUNK = 128

    def skip_random(self, n: int, gel: GelSpec, generator: torch.Generator) -> None:
        """Advance ``generator`` exactly as ``render`` of ``n`` contacts would, without
        rendering: the draws each enabled effect declares (``Effect.draws``), chunk by chunk.
        Lets the contacts of one stream render in parallel parts with the same result."""
        side = gel.size * gel.oversample
        for k in range(0, n, self.RENDER_CHUNK):
            m = min(self.RENDER_CHUNK, n - k)
            for name in self.effects_enabled:
                effect = EFFECTS[name]
                if effect.stochastic and not effect.is_neutral(self.params(name)):
                    replay_draws(effect.draws(m, (side, side), (gel.size, gel.size)), generator)

    def render(
        self,
        bank: HeightFieldBank,
        poses: Poses,
        gel: GelSpec | None = None,
        generator: torch.Generator | None = None,
        chunk: int = RENDER_CHUNK,
    ) -> torch.Tensor:
        """Real-looking images (N, 3, S, S), 0..255, of contacts ``poses`` on ``bank``.

        Randomness (pose scatter, texture, slip, noise) comes only from ``generator``;
        chunks are drawn in order, so a result depends on the generator state, not on
        ``chunk`` for the noise-free effects.
        """
        gel = gel or self.gel()
        generator = generator if generator is not None else torch.Generator().manual_seed(0)
        ctx = EffectContext(gel.width_mm, gel.height_mm, True, sensor=self.sensor)
        parts = []
        for k in range(0, len(poses), chunk):
            sub = poses.index(slice(k, k + chunk))
            sub = self._apply_effects_on("pose", sub, generator, ctx)
            with timed_span("real.height"):
                height = render_height(bank, sub, gel)
            parts.append(self.render_surface(height, gel, generator, yaw_deg=sub.yaw_deg))
        if not parts:
            return torch.zeros(0, 3, gel.size, gel.size)
        return torch.cat(parts)
