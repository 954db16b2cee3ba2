"""What an effect is: a named physical effect with typed parameters and a vectorised ``apply``.

An effect is one thing a real DIGIT does that the simple simulator does not. It acts at one
stage of the image formation, on that stage's data:

========  ==========================================  =====================================
stage     ``x`` given to ``apply``                    meaning
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
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any, ClassVar, Literal

import torch
import torch.nn.functional as F

from tactile_bench.errors import TactileBenchError

Stage = Literal["pose", "geometry", "optics", "camera"]
Draw = tuple[Literal["rand", "randn"], tuple[int, ...]]  # a torch.rand / torch.randn call
STAGES: tuple[Stage, ...] = ("pose", "geometry", "optics", "camera")
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
    """A parameter value as a float tensor (keeps autograd history)."""
    if isinstance(value, torch.Tensor):
        return value.float() if value.dtype != torch.float32 else value
    return torch.tensor(float(value), dtype=torch.float32)


class Effect(ABC):
    """Base class: subclasses set the class attributes and implement ``_apply``.

    Call ``apply(x, params, generator, context)``; missing params take their defaults.
    """

    name: ClassVar[str]
    stage: ClassVar[Stage]
    description: ClassVar[str]
    params: ClassVar[tuple[Param, ...]]
    differentiable: ClassVar[tuple[str, ...]] = ()
    stochastic: ClassVar[bool] = False

    def __init__(self) -> None:
        self._index = {p.name: p for p in self.params}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, stage={self.stage!r})"

    # ---------------------------------------------------------------- parameters
    def param(self, name: str) -> Param:
        if name not in self._index:
            raise TactileBenchError(
                f"effect {self.name!r}: unknown parameter {name!r}; known: {sorted(self._index)}"
            )
        return self._index[name]

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
        rows = [f"{self.name} ({self.stage})"]
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
    passes then runs in a core's cache instead of main memory (~1.1-1.5x faster on CPU).
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


def gaussian_kernel1d(sigma_px: torch.Tensor, radius: int) -> torch.Tensor:
    """Normalised 1-D Gaussian taps (2 radius + 1), differentiable in ``sigma_px``."""
    t = torch.arange(-radius, radius + 1, dtype=torch.float32)
    s = sigma_px.clamp(min=1e-3)
    k = torch.exp(-0.5 * (t / s) ** 2)
    return k / k.sum()


def gaussian_blur(
    x: torch.Tensor, sigma_x_px: torch.Tensor, sigma_y_px: torch.Tensor, max_radius: int = 64
) -> torch.Tensor:
    """Separable Gaussian blur of (N, C, H, W) with reflect padding; sigma in pixels.

    Wide blurs (sigma > 4 px on both axes) run on a 2x area-downsampled copy and are
    upsampled back: same result to ~1% for a smooth field. The whole 1-D blur of each axis
    (padding, taps, upsampling) is one matrix, so the blur is two GEMMs, ``Ly @ x @ Lx^T``
    (after the 2x area pooling, for a wide one): at these sizes (<= a few hundred px)
    ~15x faster on CPU than a 1-channel ``conv2d``, and differentiable in sigma through the
    matrices. Narrow blurs (taps within ``SMALL_BLUR_RADIUS`` px) of fixed sigma outside
    autograd are shifted adds of the same taps instead (``_blur_by_taps``): the dense GEMMs
    spend H + W multiply-adds a pixel whatever the radius.
    """
    h, w = x.shape[-2], x.shape[-1]
    taps = _small_blur_taps(h, w, sigma_x_px, sigma_y_px, max_radius, x)
    if taps is not None:
        return _blur_by_taps(x, *taps)
    ly, lx, pooled = _blur_factors_for(h, w, sigma_x_px, sigma_y_px, max_radius)
    if pooled:  # pool first: the GEMMs then run on a quarter of the pixels
        x = area_pool(x, 2**pooled)
    return torch.matmul(ly.to(x), torch.matmul(x, lx.to(x).T))


#: blurs whose taps reach at most this far (px) on both axes run as shifted adds
SMALL_BLUR_RADIUS = 5


def _small_blur_taps(
    h: int,
    w: int,
    sigma_x_px: ParamValue,
    sigma_y_px: ParamValue,
    max_radius: int,
    x: torch.Tensor,
) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """(x taps, y taps) of a narrow blur of fixed sigma outside autograd, else None."""
    if x.requires_grad or x.dtype != torch.float32 or x.dim() != 4:
        return None
    if any(isinstance(s, torch.Tensor) and s.requires_grad for s in (sigma_x_px, sigma_y_px)):
        return None
    return _cached_small_taps(h, w, scalar(sigma_x_px), scalar(sigma_y_px), max_radius)


@lru_cache(maxsize=64)
def _cached_small_taps(
    h: int, w: int, sx: float, sy: float, max_radius: int
) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    if max(sx, sy) > 4 or min(h, w) < 2:  # wide: the pooled GEMM path
        return None
    rx = min(max_radius, max(1, math.ceil(3.0 * sx)), w - 1)
    ry = min(max_radius, max(1, math.ceil(3.0 * sy)), h - 1)
    if max(rx, ry) > SMALL_BLUR_RADIUS:
        return None
    kx = gaussian_kernel1d(torch.tensor(sx), rx)
    ky = gaussian_kernel1d(torch.tensor(sy), ry)
    return tuple(kx.tolist()), tuple(ky.tolist())


def _blur_by_taps(x: torch.Tensor, kx: tuple[float, ...], ky: tuple[float, ...]) -> torch.Tensor:
    """The reflect-padded separable blur as a weighted sum of shifted slices, x then y.

    The same taps as ``gaussian_blur``'s matrices (equal to float rounding); for a few taps
    an add each over the image is ~2-4x cheaper than the two dense GEMMs, which spend H + W
    multiply-adds a pixel whatever the radius.
    """
    for dim, k in ((-1, kx), (-2, ky)):
        r = (len(k) - 1) // 2
        pad = (r, r, 0, 0) if dim == -1 else (0, 0, r, r)
        xp = F.pad(x, pad, mode="reflect")
        size = x.shape[dim]
        out = xp.narrow(dim, 0, size) * k[0]
        for t in range(1, 2 * r + 1):
            out.add_(xp.narrow(dim, t, size), alpha=k[t])
        x = out
    return x


def area_pool(x: torch.Tensor, factor: int) -> torch.Tensor:
    """``F.avg_pool2d(x, factor)`` of (N, C, H, W), H and W multiples of ``factor``.

    The same sums in the same order (so the same floats), as strided adds: ~2.5x faster on
    CPU than torch's pooling kernel at these sizes.
    """
    n, c, h, w = x.shape
    if h % factor or w % factor or x.requires_grad:
        return F.avg_pool2d(x, factor)
    v = x.view(n, c, h // factor, factor, w // factor, factor)
    out = v[:, :, :, 0, :, 0].clone()
    for i in range(factor):
        for j in range(factor):
            if i or j:
                out += v[:, :, :, i, :, j]
    return out.div_(factor * factor)


def blur_matrices(
    h: int, w: int, sigma_x_px: ParamValue, sigma_y_px: ParamValue, max_radius: int = 64
) -> tuple[torch.Tensor, torch.Tensor]:
    """(My (H, H), Mx (W, W)) of ``gaussian_blur``; cached unless a sigma is being fitted."""
    ly, lx, pooled = _blur_factors_for(h, w, sigma_x_px, sigma_y_px, max_radius)
    for _ in range(pooled):
        ly = ly @ _pool_matrix(ly.shape[1] * 2)
        lx = lx @ _pool_matrix(lx.shape[1] * 2)
    return ly, lx


def _blur_factors_for(
    h: int, w: int, sigma_x_px: ParamValue, sigma_y_px: ParamValue, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    sx, sy = as_tensor(sigma_x_px), as_tensor(sigma_y_px)
    if sx.requires_grad or sy.requires_grad:
        return _blur_factors(h, w, sx, sy, max_radius)
    return _cached_blur_factors(h, w, float(sx), float(sy), max_radius)


@lru_cache(maxsize=64)
def _cached_blur_factors(
    h: int, w: int, sx: float, sy: float, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    return _blur_factors(h, w, torch.tensor(sx), torch.tensor(sy), max_radius)


def _blur_factors(
    h: int, w: int, sx: torch.Tensor, sy: torch.Tensor, max_radius: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(Ly (H, H'), Lx (W, W'), k): the blur is ``Ly @ pool_k(x) @ Lx^T``, pool_k the
    2^k x 2^k area average (H' = H / 2^k)."""
    wide = float(sx.detach()) > 4 and float(sy.detach()) > 4 and min(h, w) >= 16
    if wide and h % 2 == 0 and w % 2 == 0:
        # the 2x2 box already blurs by sqrt(1/12) px (at full res); take it off
        sx2 = torch.sqrt((sx**2 - 1 / 12).clamp(min=1e-6)) / 2
        sy2 = torch.sqrt((sy**2 - 1 / 12).clamp(min=1e-6)) / 2
        ly, lx, k = _blur_factors(h // 2, w // 2, sx2, sy2, max_radius)
        return _upsample_matrix(h) @ ly, _upsample_matrix(w) @ lx, k + 1
    rx = min(max_radius, max(1, math.ceil(3.0 * float(sx.detach()))), w - 1)
    ry = min(max_radius, max(1, math.ceil(3.0 * float(sy.detach()))), h - 1)
    return (
        _conv_matrix(h, gaussian_kernel1d(sy, ry)),
        _conv_matrix(w, gaussian_kernel1d(sx, rx)),
        0,
    )


def _conv_matrix(n: int, k: torch.Tensor) -> torch.Tensor:
    """(n, n) matrix of the reflect-padded correlation with taps ``k``: the conv of an identity."""
    return _conv1d_slices(torch.eye(n)[None, None], k, -1)[0, 0].T


@lru_cache(maxsize=16)
def _pool_matrix(n: int) -> torch.Tensor:
    """(n / 2, n): 2x area downsampling along one axis."""
    return torch.eye(n).reshape(n // 2, 2, n).mean(1)


@lru_cache(maxsize=16)
def _upsample_matrix(n: int) -> torch.Tensor:
    """(n, n / 2): ``F.interpolate`` bilinear (align_corners False) 2x upsampling along one axis."""
    return resize_matrix(n, n // 2, "bilinear")


def resize_matrix(out: int, n: int, mode: str) -> torch.Tensor:
    """(out, n) matrix of a 1-D resize, built by resizing an identity with torch's own op.

    ``mode`` is ``"bilinear"`` (``F.interpolate``, align_corners False) or ``"area"``
    (``F.adaptive_avg_pool2d``); torch's 2-D resizes are separable, so two such matrices
    reproduce them.
    """
    eye = torch.eye(n)[None, None]
    if mode == "area":
        return F.adaptive_avg_pool2d(eye, (out, n))[0, 0]
    return F.interpolate(eye, size=(out, n), mode="bilinear", align_corners=False)[0, 0]


def _conv1d_slices(x: torch.Tensor, k: torch.Tensor, dim: int) -> torch.Tensor:
    """Correlate every (N, C) plane along ``dim`` with taps ``k``, reflect padding.

    The reference definition of one blur axis; ``_conv_matrix`` runs it once on an identity.
    """
    n, c, h, w = x.shape
    r = (k.numel() - 1) // 2
    pad = (r, r, 0, 0) if dim == -1 else (0, 0, r, r)
    weight = k.view(1, 1, 1, -1) if dim == -1 else k.view(1, 1, -1, 1)
    y = F.conv2d(F.pad(x.reshape(n * c, 1, h, w), pad, mode="reflect"), weight)
    return y.reshape(n, c, h, w)


@lru_cache(maxsize=32)
def pixel_grid(h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised pixel-centre coordinates u (right), v (down) in [-1, 1], each (H, W).

    Cached per size: treat the tensors as read-only.
    """
    v = (torch.arange(h, dtype=torch.float32) + 0.5) / h * 2 - 1
    u = (torch.arange(w, dtype=torch.float32) + 0.5) / w * 2 - 1
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return uu, vv


def shift_mm(
    x: torch.Tensor, dx_mm: torch.Tensor, dy_mm: torch.Tensor, ctx: EffectContext
) -> torch.Tensor:
    """Sample x at (p + d): content moves by -d. dx, dy broadcast to (N,), mm, image axes."""
    n, _, h, w = x.shape
    uu, vv = pixel_grid(h, w)
    du = (2.0 * dx_mm / ctx.width_mm).reshape(-1, 1, 1)
    dv = (2.0 * dy_mm / ctx.height_mm).reshape(-1, 1, 1)
    grid = torch.stack([(uu + du).expand(n, h, w), (vv + dv).expand(n, h, w)], dim=-1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def surface_gradient(height: torch.Tensor, ctx: EffectContext) -> tuple[torch.Tensor, torch.Tensor]:
    """Central-difference slope (dh/dx, dh/dy), mm/mm, image axes (x right, y down)."""
    dx, dy = ctx.mm_per_px(height)
    hp = F.pad(height, (1, 1, 1, 1), mode="replicate")
    gx = (hp[..., 1:-1, 2:] - hp[..., 1:-1, :-2]) / (2 * dx)
    gy = (hp[..., 2:, 1:-1] - hp[..., :-2, 1:-1]) / (2 * dy)
    return gx, gy


def randn(shape: tuple[int, ...], generator: torch.Generator | None) -> torch.Tensor:
    return torch.randn(shape, generator=generator, dtype=torch.float32)


def replay_draws(draws: list[Draw], generator: torch.Generator) -> None:
    """Take ``draws`` from ``generator`` and discard them (see ``Effect.draws``).

    Only the generator's position matters, so the draws are replaced by the cheapest call
    that consumes the same 32-bit words of its Mersenne twister: torch's CPU ``rand``
    takes one word a float32, ``randn`` one a value plus 16 when the count is not a multiple
    of 16 (its Box-Muller works in blocks of 16, recomputing the last block), for 16 values
    or more; fewer go through another algorithm and are drawn for real. The tests compare
    generator states after ``apply`` and after this.
    """
    words = 0
    for kind, shape in draws:
        n = math.prod(shape)
        if kind == "rand":
            words += n
        elif n >= 16:
            words += n + (16 if n % 16 else 0)
        else:
            skip_words(words, generator)
            words = 0
            torch.randn(shape, generator=generator, dtype=torch.float32)
    skip_words(words, generator)


def skip_words(words: int, generator: torch.Generator, block: int = 1 << 20) -> None:
    """Advance ``generator`` by ``words`` 32-bit draws (int32 ``random_`` takes one each)."""
    buffer = torch.empty(min(words, block), dtype=torch.int32)
    for k in range(0, words, block):
        buffer[: min(block, words - k)].random_(generator=generator)
