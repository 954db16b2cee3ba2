"""The no-contact frame as evidence for camera effects: a lens acts on all it sees.

The candidates composite onto the measured no-contact frame, so the pairs' gap sees only
what an effect does to the contact. A camera effect after the optics (a lens blur) also
acts on the no-contact frame, where a gel's geometry changes nothing: the measured frame
is the sim's own frame through the real lens. ``read_frame`` scores a camera candidate's
fitted parameters there: the texture of the sim's own frame taken through it, against the
measured frame's. Texture is each frame divided by its own smooth field (so a gain or a
smooth falloff drops out), compared by the gap measure's local gradient strengths, window
by window (4 x 4 px), with a bootstrap interval over the windows.

The frame cannot decide when the sim's own frame is not given (the sim was composited
onto the measured one) or when the effect changes its texture by less than 8-bit rounding
does (a smooth frame): then a camera effect and a geometry effect that both explain the
contacts are reported confusable, naming the measurement that would separate them
(``FrameCheck.cannot_read``). Where it decides, it names the effect it supports
(``FrameCheck.prefers``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import torch

from tactile_bench.diagnose.bootstrap import interval95, resampled
from tactile_bench.diagnose.candidates import CameraCandidate, get_candidate
from tactile_bench.diagnose.gapfit import gap_features
from tactile_bench.diagnose.scene import PairScene, fine_scale
from tactile_bench.effects import EFFECT_ORDER

CONFIRMS, CONTRADICTS, UNDECIDED = "confirms", "contradicts", "undecided"
NO_SIM_FRAME, NO_TEXTURE = "no sim no-contact frame", "no texture to read"
MISSING: dict[str, str] = {
    NO_SIM_FRAME: "the sim's own no-contact frame (not given: the sim was composited onto "
    "the measured one) against the measured frame: a lens blurs all it sees, a gel's "
    "geometry changes only where it is pressed",
    NO_TEXTURE: "a textured no-contact frame, sim and measured (this one is too smooth for "
    "the effect to change it beyond 8-bit rounding): a lens blurs all it sees, a gel's "
    "geometry changes only where it is pressed",
    UNDECIDED: "a no-contact frame with more texture, sim and measured (this one's does not "
    "decide): a lens blurs all it sees, a gel's geometry changes only where it is pressed",
}
#: the smooth field a frame's texture is taken over: a Gaussian of this sigma at 64 px,
#: scaled with the frame (a falloff's curvature then drops out at every size); 3 sigma
#: are left out at each edge, where the field's padding is not the frame's
SMOOTH_PX, REF_SIZE = 3.0, 64
#: an effect reads on the frame when it changes the stored frame's texture by this many
#: times what 8-bit rounding noise (uniform, one grey level wide) changes
ABOVE_ROUNDING = 2.0


@dataclass(frozen=True)
class FrameReading:
    """What the no-contact frame says of a camera effect at its fitted parameters: the
    texture gap of the sim's own frame against the measured one without and with it (grey
    level^2, mean over 4 x 4 px windows), the share it removes (-inf where the sim's frame
    is the measured one), the bootstrap 95% CI of the gap it removes (grey level^2), how
    much it changes the sim frame's texture and how much 8-bit rounding does."""

    status: str  # CONFIRMS, CONTRADICTS, UNDECIDED, NO_SIM_FRAME or NO_TEXTURE
    gap_before: float = math.nan
    gap_after: float = math.nan
    credit: float = math.nan
    ci_low: float = math.nan
    ci_high: float = math.nan
    change: float = math.nan
    rounding: float = math.nan

    @property
    def decides(self) -> bool:
        return self.status in (CONFIRMS, CONTRADICTS)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def reads_frame(name: str) -> bool:
    """True when the candidate acts on the whole frame after the optics, where the no-contact
    frame shows it (a camera effect linear in the light)."""
    cand = get_candidate(name)
    return isinstance(cand, CameraCandidate) and cand.on_no_contact_frame


def _texture(frame: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
    """(2 scales, 2, 3, W) windows' gradient strengths of ``frame`` (1, 3, S, S) over its
    smooth field, at ``level`` (3,) grey levels (a gain or a smooth falloff drops out),
    away from the edges (``SMOOTH_PX``)."""
    sigma = SMOOTH_PX * min(frame.shape[-2:]) / REF_SIZE
    flat = fine_scale(frame, sigma) * level[None, :, None, None]
    border = math.ceil(3 * sigma)
    inner = flat[..., border : flat.shape[-2] - border, border : flat.shape[-1] - border]
    _, rms = gap_features(inner)
    return torch.stack([r.reshape(2, 3, -1) for r in rms])


def window_gap(frame: torch.Tensor, target: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
    """Texture gap per 4 x 4 px window (W,) of ``frame`` against ``target`` (1, 3, S, S)."""
    diff = _texture(frame, level) - _texture(target, level)
    return diff.square().sum((0, 1, 2))


def stored(frame: torch.Tensor) -> torch.Tensor:
    """A frame as 8 bits store it, as the measured one was."""
    return frame.clamp(0.0, 255.0).round()


def _through(scene: PairScene, effects: Mapping[str, Mapping[str, float]]) -> torch.Tensor:
    """The sim's own no-contact frame (1, 3, S, S) through the effects of ``effects`` the
    frame shows, in catalogue order."""
    ctx = scene.context(stochastic=False)
    frame = scene.sim_frame
    for name in _catalogue_order(effects):
        if reads_frame(name):
            cand = get_candidate(name)
            assert isinstance(cand, CameraCandidate)
            frame = cand.through_sensor(frame, effects[name], ctx)
    return frame


def _catalogue_order(effects: Mapping[str, Any]) -> list[str]:
    return [n for n in EFFECT_ORDER if n in effects]


def read_frame(
    scene: PairScene,
    name: str,
    params: Mapping[str, float],
    selected: Mapping[str, Mapping[str, float]] | None = None,
    seed: int = 0,
) -> FrameReading | None:
    """What the no-contact frame says of candidate ``name`` at ``params``, with the
    ``selected`` effects in place; None when no frame's texture could show it there."""
    if not reads_frame(name) or not changes_texture(scene, name, params, seed):
        return None
    if not scene.sim_frame_given:
        return FrameReading(NO_SIM_FRAME)
    prior = {n: p for n, p in (selected or {}).items() if n != name}
    with torch.no_grad():
        measured = scene.measured[None].float()
        level = measured.mean((0, 2, 3))
        before_frame = stored(_through(scene, prior))
        after_frame = stored(_through(scene, {**prior, name: params}))
        before = window_gap(before_frame, measured, level)
        after = window_gap(after_frame, measured, level)
        change = float(window_gap(after_frame, before_frame, level).mean())
        rounding = rounding_change(before_frame, level, torch.Generator().manual_seed(seed))
    b, a = float(before.mean()), float(after.mean())
    if change <= ABOVE_ROUNDING * rounding:
        return FrameReading(NO_TEXTURE, b, a, change=change, rounding=rounding)
    # mean texture gap removed over resampled windows: decided by its sign even where the
    # sim's frame is the measured one (``before`` 0)
    lo, hi = interval95((before - after)[resampled(len(before), seed)].mean(1))
    status = CONFIRMS if lo > 0 else CONTRADICTS if hi < 0 else UNDECIDED
    credit = (b - a) / b if b > 0 else -math.inf
    return FrameReading(status, b, a, credit, lo, hi, change, rounding)


def changes_texture(scene: PairScene, name: str, params: Mapping[str, float], seed: int) -> bool:
    """True when the candidate at ``params`` changes the texture of a textured frame (seeded
    noise of 16 grey levels about 128, the scene's size) beyond 8-bit rounding: a blur does, a
    smooth gain does not, and for it the frame's texture is no evidence either way."""
    gen = torch.Generator().manual_seed(seed)
    device = scene.sim_frame.device
    probe = (120.0 + 16.0 * torch.rand(1, 3, scene.size, scene.size, generator=gen)).to(device)
    level = probe.new_full((3,), 128.0)
    cand = get_candidate(name)
    assert isinstance(cand, CameraCandidate)
    with torch.no_grad():
        through = cand.through_sensor(probe, params, scene.context(stochastic=False))
        change = float(window_gap(through, probe, level).mean())
        rounding = rounding_change(probe, level, gen)
    return change > ABOVE_ROUNDING * rounding


def rounding_change(frame: torch.Tensor, level: torch.Tensor, gen: torch.Generator) -> float:
    """How much 8-bit rounding changes ``frame``'s texture: the mean window gap of the frame
    against itself plus uniform noise one grey level wide (the yardstick of ``ABOVE_ROUNDING``)."""
    dither = (torch.rand(frame.shape, generator=gen) - 0.5).to(frame.device)
    return float(window_gap(frame + dither, frame, level).mean())


def lens_of(a: str, b: str) -> str | None:
    """The camera effect of a (camera effect the frame shows, geometry effect) pair, else
    None: the pair the no-contact frame separates."""
    for cam, other in ((a, b), (b, a)):
        if reads_frame(cam) and get_candidate(other).acts_on == "geometry":
            return cam
    return None


class FrameCheck:
    """The no-contact frame's reading of each option of a round (``options``: name -> its
    fitted parameters with ``selected`` in place), computed once and only when asked."""

    def __init__(
        self,
        scene: PairScene,
        options: Mapping[str, Mapping[str, float]],
        selected: Mapping[str, Mapping[str, float]],
        seed: int = 0,
    ) -> None:
        self.scene, self.options, self.selected, self.seed = scene, options, selected, seed
        self._readings: dict[str, FrameReading | None] = {}

    def reading(self, name: str) -> FrameReading | None:
        if name not in self._readings:
            self._readings[name] = read_frame(
                self.scene, name, self.options[name], self.selected, self.seed
            )
        return self._readings[name]

    def prefers(self, other: str, best: str) -> bool:
        """True when the frame names ``other`` in place of ``best``, a lens and a gel
        effect: a lens effect the frame confirms over a gel effect, or a gel effect over a
        lens effect the frame contradicts."""
        lens = lens_of(best, other)
        if lens is None:
            return False
        status = getattr(self.reading(lens), "status", None)
        return (lens == other and status == CONFIRMS) or (lens == best and status == CONTRADICTS)

    def cannot_read(self, a: str, b: str) -> str:
        """What is missing when ``a`` and ``b`` are a lens and a gel effect and the frame
        cannot read the lens; "" otherwise."""
        lens = lens_of(a, b)
        reading = self.reading(lens) if lens is not None else None
        return MISSING[reading.status] if reading and reading.status in MISSING else ""
