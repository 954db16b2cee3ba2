"""Contact poses of the sensor on a braille block, and the paper's two data protocols.

A contact is the block translated by (x_mm, y_mm) in the gel plane, rotated by yaw_deg about
the sensor centre and pressed so that its highest point sits press_mm into the gel.
``labels[i]`` indexes the character tuple the poses were made from (``CHARACTERS`` by
default), and the same tuple must be used to build the height-field bank.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, fields

import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS

#: Press depths (mm of dot penetration into the gel). All are below the 1.1 mm dome height of
#: ``BrailleSpec``, so only the dots touch the gel (the flat top stays 0.2-0.8 mm away), as in
#: the paper's force-controlled presses on the printed characters.
PRESS_DEPTHS_MM: tuple[float, ...] = (0.3, 0.5, 0.7, 0.9)
FINETUNE_YAWS_DEG: tuple[float, ...] = (-90.0, -45.0, 0.0, 45.0, 90.0)
CLASSIFIER_YAWS_DEG: tuple[float, ...] = tuple(float(y) for y in range(-25, 26, 5))


@dataclass
class Poses:
    """N contact poses as parallel 1-D tensors (labels int64; mm and degrees float32)."""

    labels: torch.Tensor
    x_mm: torch.Tensor
    y_mm: torch.Tensor
    yaw_deg: torch.Tensor
    press_mm: torch.Tensor

    def __post_init__(self) -> None:
        self.labels = torch.as_tensor(self.labels, dtype=torch.int64).reshape(-1)
        n = len(self.labels)
        for name in ("x_mm", "y_mm", "yaw_deg", "press_mm"):
            value = torch.as_tensor(getattr(self, name), dtype=torch.float32).reshape(-1)
            if len(value) != n:
                raise TactileBenchError(f"Poses.{name}: {len(value)} values for {n} labels")
            setattr(self, name, value)

    def __len__(self) -> int:
        return len(self.labels)

    def index(self, idx: torch.Tensor | slice | Sequence[int]) -> Poses:
        """The poses at ``idx`` (indices, boolean mask or slice), as a new ``Poses``."""
        if not isinstance(idx, slice):
            idx = torch.as_tensor(idx)
            if idx.dtype != torch.bool:
                idx = idx.long()
        return Poses(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})

    subset = index

    @classmethod
    def cat(cls, parts: Sequence[Poses]) -> Poses:
        return cls(**{f.name: torch.cat([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    def to_dict(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def grid_protocol(
    chars: Sequence[str],
    offsets_mm: Sequence[float],
    press_mm: Sequence[float],
    yaws_deg: Sequence[float],
) -> Poses:
    """Every (character, yaw, depth, x, y) combination, character-major."""
    known = set(CHARACTERS)
    bad = [c for c in chars if c not in known]
    if bad:
        raise TactileBenchError(f"unknown braille characters {bad}")
    rows = list(itertools.product(range(len(chars)), yaws_deg, press_mm, offsets_mm, offsets_mm))
    cols = list(zip(*rows, strict=True)) if rows else [[]] * 5
    return Poses(
        labels=torch.tensor(cols[0], dtype=torch.int64),
        yaw_deg=torch.tensor(cols[1], dtype=torch.float32),
        press_mm=torch.tensor(cols[2], dtype=torch.float32),
        x_mm=torch.tensor(cols[3], dtype=torch.float32),
        y_mm=torch.tensor(cols[4], dtype=torch.float32),
    )


def finetune_test_protocol(
    chars: Sequence[str] = CHARACTERS, press_mm: Sequence[float] = PRESS_DEPTHS_MM
) -> Poses:
    """The fine-tune/test grid: 3 x 3 XY at +-5 mm, 4 depths, yaw 0, +-45, +-90 (180 a char)."""
    return grid_protocol(chars, (-5.0, 0.0, 5.0), press_mm, FINETUNE_YAWS_DEG)


def classifier_protocol(
    chars: Sequence[str] = CHARACTERS, press_mm: Sequence[float] = PRESS_DEPTHS_MM
) -> Poses:
    """The classifier grid: 3 x 3 XY at +-3 mm, 4 depths, yaw -25..25 step 5 (396 a char)."""
    return grid_protocol(chars, (-3.0, 0.0, 3.0), press_mm, CLASSIFIER_YAWS_DEG)


def classifier_test_protocol(
    chars: Sequence[str] = CHARACTERS,
    n: int = 837,
    seed: int = 0,
    press_mm: Sequence[float] = PRESS_DEPTHS_MM,
) -> Poses:
    """Test contacts for the classifiers: the sensor upright as in the classifier protocol,
    but off the grid (uniform in +-3 mm XY and +-25 deg yaw, depth within the grid's range).

    The original code tests its classifiers on a separately collected real set, not on the
    fine-tuning grid (whose +-45 and +-90 deg yaws a classifier trained on +-25 deg has never
    seen); drawing off-grid poses keeps test contacts distinct from every training contact.
    ``n`` is spread over the characters as evenly as possible.
    """
    known = set(CHARACTERS)
    bad = [c for c in chars if c not in known]
    if bad:
        raise TactileBenchError(f"unknown braille characters {bad}")
    gen = torch.Generator().manual_seed(seed)
    k = len(chars)
    labels = torch.arange(n) % k
    labels = labels[torch.randperm(n, generator=gen)].sort().values

    def uniform(low: float, high: float) -> torch.Tensor:
        return low + (high - low) * torch.rand(n, generator=gen)

    return Poses(
        labels=labels.to(torch.int64),
        x_mm=uniform(-3.0, 3.0),
        y_mm=uniform(-3.0, 3.0),
        yaw_deg=uniform(min(CLASSIFIER_YAWS_DEG), max(CLASSIFIER_YAWS_DEG)),
        press_mm=uniform(min(press_mm), max(press_mm)),
    )
