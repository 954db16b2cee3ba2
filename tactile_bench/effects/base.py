"""What an effect is: a named physical effect with typed parameters and a vectorised ``apply``.

An effect is one thing a real DIGIT does that the simple simulator does not. It acts on one
part of the image formation (its ``acts_on``), on that part's data:

========  ==========================================  =====================================
acts_on   ``x`` given to ``apply``                    meaning
========  ==========================================  =====================================
pose      ``geometry.contacts.Poses``                 where the object really touched
geometry  signed height (N, 1, H, W), mm              object surface / gel displacement
optics    ``OpticalScene``                            light leaving the gel towards the camera
camera    image (N, 3, S, S), 0..255                  what the camera and its stream make of it
========  ==========================================  =====================================

Every parameter has a physical unit, a default with a cited source, a plausible range and a
neutral value at which ``apply`` is the identity. Randomness comes only from the
``generator`` passed in (or, for properties fixed in a unit such as gel dust, from a seed
parameter), so results are reproducible. Effects are differentiable in the parameters listed
in ``differentiable``, so the gap diagnosis can fit them by gradient descent.

This module is the interface only; the numeric kernels effects are built from (blur, pooling,
resize, pixel grid, slope) are in ``effects.kernels`` and the random draws in ``effects.draws``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal

import torch

from tactile_bench.errors import TactileBenchError

ActsOn = Literal["pose", "geometry", "optics", "camera"]
Draw = tuple[Literal["rand", "randn"], tuple[int, ...]]  # a torch.rand / torch.randn call
#: the parts of image formation an effect acts on, in the order they happen
IMAGE_FORMATION: tuple[ActsOn, ...] = ("pose", "geometry", "optics", "camera")
ParamValue = torch.Tensor | float


@dataclass(frozen=True)
class Param:
    """One physical parameter: unit, default (with its source), plausible range, neutral value."""

    name: str
    unit: str
    default: float
    low: float
    high: float
    neutral: float
    source: str
    description: str = ""
    integer: bool = False

    def __post_init__(self) -> None:
        for v in (self.default, self.neutral):
            if not self.low <= v <= self.high:
                raise ValueError(f"Param {self.name}: {v} outside [{self.low}, {self.high}]")


@dataclass(frozen=True)
class EffectContext:
    """What an effect may need besides its input: the gel's extent and the render mode.

    ``stochastic`` is False when rendering a unit's no-contact reference frame: effects that
    draw per-frame randomness (noise, slip) then leave the frame unchanged.
    """

    width_mm: float = 18.0
    height_mm: float = 24.0
    stochastic: bool = True
    yaw_deg: torch.Tensor | None = None  # (N,) contact yaw, for texture fixed to the object
    sensor: str = "digit"  # whose fitted optics (response, LED layout) the optics effects use

    def mm_per_px(self, x: torch.Tensor) -> tuple[float, float]:
        """(x, y) pixel size in mm of an image-like tensor whose last two dims are (H, W)."""
        return self.width_mm / x.shape[-1], self.height_mm / x.shape[-2]


@dataclass
class OpticalScene:
    """The light field at the gel, before the camera: ``image = gain * (background + delta)``.

    ``height`` is the gel displacement towards the camera (mm, >= 0), ``background`` the
    no-contact light (0..255), ``delta`` the colour change the deformation causes (0..255
    units), ``gain`` a multiplicative transmittance (shadows, dust). All (N|1, C, H, W).
    """

    height: torch.Tensor
    background: torch.Tensor
    delta: torch.Tensor
    gain: torch.Tensor

    def composite(self) -> torch.Tensor:
        """Light reaching the sensor; the sensor saturates at 0..255."""
        light = self.background + self.delta
        if light.requires_grad or self.gain.requires_grad or light.dim() != self.gain.dim():
            return (self.gain * light).clamp(0.0, 255.0)
        if torch.broadcast_shapes(light.shape, self.gain.shape) != light.shape:
            light = light.expand(torch.broadcast_shapes(light.shape, self.gain.shape)).clone()
        return light.mul_(self.gain).clamp_(0.0, 255.0)  # in place: same values, no copies

    def replace(self, **changes: torch.Tensor) -> OpticalScene:
        return replace(self, **changes)


def as_tensor(value: ParamValue, like: torch.Tensor | None = None) -> torch.Tensor:
    """A parameter value as a float tensor (keeps autograd history), on ``like``'s device
    when given."""
    device = None if like is None else like.device
    if isinstance(value, torch.Tensor):
        value = value.float() if value.dtype != torch.float32 else value
        return value if device is None else value.to(device)
    return torch.tensor(float(value), dtype=torch.float32, device=device)


class Effect(ABC):
    """Base class: subclasses set the class attributes and implement ``_apply``.

    Call ``apply(x, params, generator, context)``; missing params take their defaults.
    """

    name: ClassVar[str]
    acts_on: ClassVar[ActsOn]
    description: ClassVar[str]
    params: ClassVar[tuple[Param, ...]]
    differentiable: ClassVar[tuple[str, ...]] = ()
    stochastic: ClassVar[bool] = False

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, acts_on={self.acts_on!r})"

    # ---------------------------------------------------------------- parameters
    def param(self, name: str) -> Param:
        """The parameter called ``name`` (an effect has a handful: a scan is enough)."""
        for p in self.params:
            if p.name == name:
                return p
        known = sorted(p.name for p in self.params)
        raise TactileBenchError(f"effect {self.name!r}: unknown parameter {name!r}; known: {known}")

    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.params}

    def neutral_params(self) -> dict[str, float]:
        """Parameter values at which ``apply`` returns its input unchanged."""
        return {p.name: p.neutral for p in self.params}

    def validate(self, params: Mapping[str, ParamValue] | None = None) -> dict[str, ParamValue]:
        """Fill defaults and check names and ranges; raise ``TactileBenchError`` otherwise."""
        out: dict[str, ParamValue] = dict(self.defaults())
        for key, value in (params or {}).items():
            p = self.param(key)
            if isinstance(value, bool) or not isinstance(value, int | float | torch.Tensor):
                raise TactileBenchError(
                    f"effect {self.name!r}: parameter {key!r} must be a number, got {value!r}"
                )
            if isinstance(value, torch.Tensor):
                t = value.detach()
            else:
                t = torch.tensor(value, dtype=torch.float64)
            if not bool(torch.isfinite(t).all()):
                raise TactileBenchError(f"effect {self.name!r}: parameter {key!r} is not finite")
            lo, hi = float(t.min()), float(t.max())
            # bounds rounded as the value was: a float32 0.1 is a valid upper bound 0.1
            low, high = (float(torch.tensor(b, dtype=t.dtype)) for b in (p.low, p.high))
            if lo < low or hi > high:
                raise TactileBenchError(
                    f"effect {self.name!r}: parameter {key!r} = {value if t.numel() == 1 else t}"
                    f" {p.unit} outside its range [{p.low}, {p.high}]"
                )
            out[key] = value
        return out

    def is_neutral(self, params: Mapping[str, ParamValue]) -> bool:
        """True when every value is its neutral one and no differentiable one is being fitted."""
        for p in self.params:
            v = params[p.name]
            if isinstance(v, torch.Tensor):
                if v.requires_grad and p.name in self.differentiable:
                    return False
                if not bool((v.detach() == p.neutral).all()):
                    return False
            elif float(v) != p.neutral:
                return False
        return True

    # ---------------------------------------------------------------- application
    def apply(
        self,
        x: Any,
        params: Mapping[str, ParamValue] | None = None,
        generator: torch.Generator | None = None,
        context: EffectContext | None = None,
    ) -> Any:
        """Apply the effect to a batch; the identity at ``neutral_params()``."""
        p = self.validate(params)
        if self.is_neutral(p):
            return x
        ctx = context or EffectContext()
        if self.stochastic and ctx.stochastic and generator is None:
            generator = torch.Generator().manual_seed(0)
        return self._apply(x, p, generator, ctx)

    @abstractmethod
    def _apply(
        self,
        x: Any,
        p: Mapping[str, ParamValue],
        generator: torch.Generator | None,
        ctx: EffectContext,
    ) -> Any: ...

    def draws(self, n: int, render_hw: tuple[int, int], image_hw: tuple[int, int]) -> list[Draw]:
        """The random draws ``apply`` takes from its generator for a batch of ``n`` contacts
        rendered at ``render_hw`` into ``image_hw`` images, in order (when not neutral and
        rendering stochastically). Replaying them advances a generator past a batch without
        rendering it, so a stream of batches can be split over threads with the same result
        (``SurrogateDigit.skip_random``); tests check every effect's list against ``apply``.
        """
        return []

    def summary(self) -> str:
        """One line per parameter: name, unit, default, range, neutral, source."""
        rows = [f"{self.name} ({self.acts_on})"]
        for q in self.params:
            rows.append(
                f"  {q.name} [{q.unit}] default {q.default} range [{q.low}, {q.high}] "
                f"neutral {q.neutral} -- {q.source}"
            )
        return "\n".join(rows)


# ---------------------------------------------------------------------------- helpers
SUB_BATCH_ELEMENTS = 1 << 18  # values per image slice x images per pass (1 MB of float32)


def per_sub_batch(
    fn: Callable[..., torch.Tensor], *xs: Any, size: int | None = None
) -> torch.Tensor:
    """``fn(*xs)`` evaluated on consecutive slices of the batch and concatenated.

    Same result (every image is computed on its own), but each of ``fn``'s many elementwise
    passes then runs in a core's cache instead of main memory.
    By default a slice holds ~``SUB_BATCH_ELEMENTS`` values of ``xs[0]``. Tensors whose
    first dim is not the batch (broadcast ones, scalars) and non-tensors go in whole.
    """
    n = xs[0].shape[0]
    size = size or max(1, SUB_BATCH_ELEMENTS // max(1, xs[0][:1].numel()))
    if n <= size:
        return fn(*xs)

    def part(x: Any, i: int) -> Any:
        sliced = isinstance(x, torch.Tensor) and x.dim() > 0 and x.shape[0] == n
        return x[i : i + size] if sliced else x

    first = fn(*(part(x, 0) for x in xs))
    rest = (fn(*(part(x, i) for x in xs)) for i in range(size, n, size))
    if first.requires_grad:
        return torch.cat([first, *rest])
    # each slice copied into the result while still in cache (``cat`` at the end reads them
    # all back from memory): the same values
    out = first.new_empty((n, *first.shape[1:]))
    out[:size].copy_(first)
    del first
    for i, result in zip(range(size, n, size), rest, strict=True):
        out[i : i + size].copy_(result)
    return out


def scalar(value: ParamValue) -> float:
    """A parameter value as a plain float (for shapes, counts, seeds: not differentiated)."""
    return float(value.detach()) if isinstance(value, torch.Tensor) else float(value)
