"""A braille label strip and the frames of a DIGIT sliding along it.

The paper closes with a demo: a DIGIT slides over a printed braille label and the
classifier reads the word DIGIT. Here the label is the word's cells in a row on a flat
plate, at the project's scaled ``BrailleSpec``. ``BrailleSpec`` has no cell pitch (each of the
paper's prints holds a single cell), so we take the braille standard's ratio of cell pitch
to dot spacing, ``CELL_PITCH_RATIO`` = 2.7 (e.g. 6.2 mm / 2.3 mm in the US Library of
Congress specification): 2.7 x 5.5 mm = 14.85 mm, rounded to the height field's grid
(14.83 mm). The 18 mm wide gel then sees one whole cell when centred on it, and parts of
two cells in between.

The strip is a height field, not a new mesh: each character's field is ray-cast once by
``sensor.heightfield.build_bank`` (the same fields the classifier's training contacts came
from), clipped to the plate (the flat top is 0, the dots are positive) and pasted at its
cell's offset. A frame is a square window of that field around the sensor centre, so
frames render through the very code that rendered the training contacts
(``SurrogateDigit.render``: pose scatter, press error, texture, optics, camera) with the
sensor upright and the press measured from the dot peaks, as in ``sensor.depth``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from tactile_bench.data.pixels import image_to_foreground, to_uint8
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import HeightFieldBank, build_bank

#: Cell pitch / dot spacing of standard braille (cell pitch 6.0-6.4 mm, dots 2.3-2.5 mm).
CELL_PITCH_RATIO = 2.7
#: Window margin (mm) beyond the gel's larger half-side, so bilinear sampling never clamps.
_WINDOW_MARGIN_MM = 1.0


def check_word(word: str) -> str:
    """The word in upper case (braille letters have no case), or an error naming a bad char."""
    if not word:
        raise TactileBenchError("--word: empty; give at least one braille character")
    upper = word.upper()
    for char in upper:
        if char not in CHARACTERS:
            raise TactileBenchError(
                f"--word: {char!r} is not one of the 27 braille classes ({''.join(CHARACTERS)})"
            )
    return upper


def cell_pitch_mm(spec: BrailleSpec | None = None) -> float:
    """Nominal centre-to-centre distance of neighbouring cells: ``CELL_PITCH_RATIO`` x dots."""
    return CELL_PITCH_RATIO * (spec or BrailleSpec()).dot_spacing_mm


@dataclass
class LabelStrip:
    """The word's cells on a plate: ``heights`` (H, W) mm above the plate, row 0 at +y.

    Column ``j`` lies at x = (j - ``origin_col``) * ``resolution_mm``: x = 0 is the first
    cell's centre, cell ``i`` is at ``i * pitch_mm``. Rows cover +-``half_mm`` in y, the
    half-side of a frame's window.
    """

    word: str
    heights: torch.Tensor
    resolution_mm: float
    pitch_mm: float
    origin_col: int
    half_mm: float
    spec: BrailleSpec

    @property
    def cell_x_mm(self) -> np.ndarray:
        """(n,) x of each cell's centre, mm."""
        return np.arange(len(self.word)) * self.pitch_mm

    @property
    def dot_height_mm(self) -> float:
        return float(self.heights.max())

    @property
    def half_cols(self) -> int:
        return int(round(self.half_mm / self.resolution_mm))

    def travel_mm(self, step_mm: float) -> np.ndarray:
        """Sensor centres every ``step_mm`` from half a pitch before the first cell centre to
        half a pitch after the last, on a grid through the first cell's centre."""
        if not step_mm > 0:
            raise TactileBenchError(f"--step-mm: must be > 0, got {step_mm}")
        half = self.pitch_mm / 2
        first = math.ceil(-half / step_mm - 1e-9)
        last = math.floor((self.cell_x_mm[-1] + half) / step_mm + 1e-9)
        return np.arange(first, last + 1) * step_mm

    def window_bank(self, x_mm: Sequence[float], press_mm: float) -> tuple[HeightFieldBank, Poses]:
        """A bank holding one window of the strip per frame, and the frames' poses on it.

        Window ``k`` is centred on the grid column nearest ``x_mm[k]``; the pose shifts it by
        the remaining sub-step distance. The press is measured from the dot peaks of the
        whole strip (the plate is flat, so from the same height in every frame).
        """
        x = np.asarray(x_mm, dtype=np.float64)
        k = self.half_cols
        cols = self.origin_col + np.rint(x / self.resolution_mm).astype(np.int64)
        if len(x) and (cols.min() - k < 0 or cols.max() + k >= self.heights.shape[1]):
            raise TactileBenchError(
                f"read: sensor position outside the strip ({x.min():.1f}..{x.max():.1f} mm)"
            )
        maps = torch.stack([self.heights[:, c - k : c + k + 1] for c in cols.tolist()])
        bank = HeightFieldBank(
            maps=maps[:, None],
            chars=tuple(str(i) for i in range(len(x))),
            half_extent_mm=k * self.resolution_mm,
            far_mm=0.0,
            spec=self.spec,
        )
        residual = x - (cols - self.origin_col) * self.resolution_mm
        n = len(x)
        # render_height presses each map's own peak press_mm deep; a window without a whole
        # cell (only with a pitch far above the gel width) has a lower peak: press less there
        press = float(press_mm) - (self.dot_height_mm - bank.top_max)
        poses = Poses(
            labels=torch.arange(n),
            x_mm=torch.from_numpy(-residual),  # the strip moves by -residual under the gel
            y_mm=torch.zeros(n),
            yaw_deg=torch.zeros(n),
            press_mm=press,
        )
        return bank, poses


def build_strip(
    word: str,
    spec: BrailleSpec | None = None,
    gel: GelSpec | None = None,
    pitch_mm: float | None = None,
    resolution_mm: float = 0.1,
) -> LabelStrip:
    """The label strip of ``word`` (validated, upper-cased) at ``pitch_mm`` (default
    ``cell_pitch_mm(spec)``, rounded to the height field's grid step)."""
    word = check_word(word)
    spec = spec or BrailleSpec()
    gel = gel or GelSpec()
    pitch = cell_pitch_mm(spec) if pitch_mm is None else float(pitch_mm)
    cell_extent = spec.dot_spacing_mm + spec.dot_base_diameter_mm  # width of a cell's dots
    if not pitch > cell_extent:
        raise TactileBenchError(f"--pitch-mm: {pitch} mm is below a cell's width {cell_extent} mm")
    chars = tuple(sorted(set(word)))
    bank = _cell_bank(chars, spec, resolution_mm)
    res = bank.resolution_mm
    pitch_cols = int(round(pitch / res))
    k = math.ceil((max(gel.width_mm, gel.height_mm) / 2 + _WINDOW_MARGIN_MM) / res)
    cell_maps = bank.maps[:, 0].clamp(min=0.0)  # off-block (the table) becomes plate
    kb = (cell_maps.shape[-1] - 1) // 2
    # rows: centre-aligned crop or zero-pad of the cell fields to the window's 2k + 1
    if kb >= k:
        cell_maps = cell_maps[:, kb - k : kb + k + 1]
    else:
        cell_maps = torch.nn.functional.pad(cell_maps, (0, 0, k - kb, k - kb))
    lead = k + pitch_cols // 2 + 2  # room for a window around the first/last sensor centre
    origin = lead
    width = origin + (len(word) - 1) * pitch_cols + lead + 1
    heights = torch.zeros(2 * k + 1, width)
    for i, char in enumerate(word):
        centre = origin + i * pitch_cols
        lo, hi = max(centre - kb, 0), min(centre + kb + 1, width)
        patch = cell_maps[chars.index(char), :, lo - (centre - kb) : hi - (centre - kb)]
        heights[:, lo:hi] = torch.maximum(heights[:, lo:hi], patch)
    return LabelStrip(
        word=word,
        heights=heights,
        resolution_mm=res,
        pitch_mm=pitch_cols * res,
        origin_col=origin,
        half_mm=k * res,
        spec=spec,
    )


@functools.lru_cache(maxsize=4)
def _cell_bank(chars: tuple[str, ...], spec: BrailleSpec, resolution_mm: float) -> HeightFieldBank:
    """The characters' height fields, ray-cast once per process (a CLI call or a test file
    reading several words pays for each character once)."""
    return build_bank(chars, spec, resolution_mm=resolution_mm)


@dataclass
class StripFrames:
    """Frames of the sliding sensor: centres ``x_mm`` (N,), sim ``depth`` (N, 1, S, S) mm of
    the commanded contacts, ``images`` (N, 3, S, S) uint8 of the real sensor, its
    ``background`` (3, S, S) uint8."""

    x_mm: np.ndarray
    depth: torch.Tensor
    images: torch.Tensor
    background: torch.Tensor

    def foreground(self) -> torch.Tensor:
        """(image - background) / 255 + 0.5: what the classifiers take."""
        return image_to_foreground(self.images.float(), self.background.float())


def render_frames(
    strip: LabelStrip,
    x_mm: Sequence[float],
    sensor: object,
    press_mm: float = 0.6,
    gel: GelSpec | None = None,
    generator: torch.Generator | None = None,
    chunk: int = 64,
) -> StripFrames:
    """Render the sensor upright at ``x_mm`` along the strip, ``press_mm`` into the dots.

    ``sensor`` is a real sensor like ``SurrogateDigit`` (``render(bank, poses, gel,
    generator)`` and ``background(gel)``). Images and background are rounded to uint8 as
    the braille data sets store them, so foregrounds match the classifier's training input.
    """
    gel = gel or GelSpec()
    if not 0 < press_mm <= strip.dot_height_mm:
        raise TactileBenchError(
            f"--press-mm: must be in (0, {strip.dot_height_mm:g}] (the dot height), got {press_mm}"
        )
    generator = generator if generator is not None else torch.Generator().manual_seed(0)
    x = np.asarray(x_mm, dtype=np.float64)
    depth, images = [], []
    for k in range(0, len(x), chunk):
        bank, poses = strip.window_bank(x[k : k + chunk], press_mm)
        depth.append(to_depth(render_height(bank, poses, gel), gel))
        images.append(sensor.render(bank, poses, gel, generator))  # type: ignore[attr-defined]
    s = gel.size
    background = sensor.background(gel)  # type: ignore[attr-defined]
    return StripFrames(
        x_mm=x,
        depth=torch.cat(depth) if depth else torch.zeros(0, 1, s, s),
        images=to_uint8(torch.cat(images) if images else torch.zeros(0, 3, s, s)),
        background=to_uint8(background),
    )
