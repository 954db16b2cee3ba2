"""The one base of the paired-data containers: sim and real images of the same contacts.

``data.braille.BrailleSet``, ``data.corpus.CorpusPairs``, ``diagnose.paired.DiagnosisPairs`` and
``data.ball_presses.BallPresses`` (real presses only) share a core: gel depth (N,1,S,S) mm,
sim and real images (N,3,S,S) and the no-contact frames (3,S,S) they were taken on.
``Pairs`` checks those shapes, counts and subsets the pairs and makes their foregrounds
(through ``pixels.image_to_foreground``, the one formula), so each container keeps only
what is its own. ``Pairs`` declares no dataclass fields: each container keeps its own
constructor, whose argument order its callers rely on.
"""

from __future__ import annotations

from collections.abc import Sequence, Sized
from dataclasses import replace
from typing import Any, ClassVar, Literal, TypeAlias, TypeVar

import numpy as np
import torch

from tactile_bench.data.pixels import image_to_foreground
from tactile_bench.errors import TactileBenchError

#: what ``subset`` takes: pair positions, a boolean mask over the pairs, or a slice
Index: TypeAlias = torch.Tensor | np.ndarray | slice | Sequence[int]
Kind = Literal["sim", "real"]
KINDS: tuple[str, ...] = ("sim", "real")
_P = TypeVar("_P", bound="Pairs")


def shape_error(
    owner: str, field: str, form: str, got: Sequence[int], want: Sequence[int] | None = None
) -> TactileBenchError:
    """The one wording of a shape error: the container, the field, the form it must have."""
    here = f" = {tuple(want)}" if want is not None else ""
    return TactileBenchError(f"{owner}: {field} must be {form}{here}, got {tuple(got)}")


class Pairs:
    """Base of a dataclass of N pairs with fields ``depth``, ``sim`` and ``real``.

    A subclass calls ``_check_pairs`` in ``__post_init__`` and says in class variables what
    differs: its per-pair tensors (``PER_PAIR``), its single no-contact frames (``FRAMES``),
    which field is each kind's background (``BACKGROUNDS``) and which fields may be None
    (``OPTIONAL``). It overrides ``_subset_own`` for per-pair fields that are not tensors,
    and ``_background`` when its backgrounds are not one frame per kind. A container that
    never has sim images (real presses) sets ``sim`` as a class variable None, optional.
    """

    PER_PAIR: ClassVar[tuple[str, ...]] = ("depth", "sim", "real")
    FRAMES: ClassVar[tuple[str, ...]] = ("sim_background", "real_background")
    BACKGROUNDS: ClassVar[dict[str, str]] = {"sim": "sim_background", "real": "real_background"}
    OPTIONAL: ClassVar[frozenset[str]] = frozenset()

    depth: torch.Tensor
    sim: torch.Tensor | None
    real: torch.Tensor

    def __len__(self) -> int:
        return len(self.depth)

    # ------------------------------------------------------------------ checks
    def _check_pairs(self, **also: Sized) -> None:
        """Raise a ``TactileBenchError`` naming the first field that does not pair with
        ``depth`` (N,1,S,S): sim and real (N,3,S,S), ``FRAMES`` (3,S,S), and N entries in the
        other ``PER_PAIR`` fields and in ``also`` (the subclass's lists, poses, ...)."""
        owner = type(self).__name__
        if self.depth.dim() != 4 or self.depth.shape[1] != 1:
            raise shape_error(owner, "depth", "(N,1,S,S)", self.depth.shape)
        n, size = len(self.depth), tuple(self.depth.shape[2:])
        for name in ("sim", "real"):
            self._check_shape(name, "(N,3,S,S)", (n, 3, *size))
        for name in self.FRAMES:
            self._check_shape(name, "(3,S,S)", (3, *size))
        counted = {k: self._field(k) for k in self.PER_PAIR if k not in ("depth", "sim", "real")}
        for name, value in (counted | also).items():
            if value is not None and len(value) != n:
                raise TactileBenchError(
                    f"{owner}: {name} must have one entry per pair (N = {n}), got {len(value)}"
                )

    def _field(self, name: str) -> Any:
        """The field ``name``; None only where ``OPTIONAL`` allows it."""
        value = getattr(self, name)
        if value is None and name not in self.OPTIONAL:
            raise TactileBenchError(f"{type(self).__name__}: {name} is missing (None)")
        return value

    def _check_shape(self, name: str, form: str, want: tuple[int, ...]) -> None:
        value = self._field(name)
        if value is not None and tuple(value.shape) != want:
            raise shape_error(type(self).__name__, name, form, value.shape, want)

    # ------------------------------------------------------------------ subsets
    def subset(self: _P, idx: Index) -> _P:
        """The pairs at ``idx`` (positions, boolean mask or slice) as a new, re-checked set
        of the same class; the no-contact frames are shared, not copied."""
        index = self._index(idx)
        tensors = {k: _take(getattr(self, k), index) for k in self.PER_PAIR}
        return replace(self, **tensors, **self._subset_own(index))  # type: ignore[type-var]

    def to(self: _P, device: torch.device | str) -> _P:
        """The same pairs with every tensor (per pair, and the frames) on ``device``: moved
        once, so the work that follows never copies them again."""
        fields = (*self.PER_PAIR, *self.FRAMES)
        moved = {
            k: v.to(device) for k in fields if isinstance(v := getattr(self, k, None), torch.Tensor)
        }
        return replace(self, **moved)  # type: ignore[type-var]

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        """The subclass's per-pair fields that are not tensors, at ``index``."""
        return {}

    def _index(self, idx: Index) -> torch.Tensor | slice:
        """``idx`` as torch indexes: a slice as it is, a mask checked against N, else int64."""
        if isinstance(idx, slice):
            return idx
        index = torch.as_tensor(idx)
        if index.dtype != torch.bool:
            return index.long()
        if tuple(index.shape) != (len(self),):
            raise TactileBenchError(
                f"{type(self).__name__}.subset: a mask of shape {tuple(index.shape)} "
                f"for {len(self)} pairs"
            )
        return index

    def _positions(self, index: torch.Tensor | slice) -> list[int]:
        """The pair numbers ``index`` selects, in order: to subset plain lists alike."""
        if isinstance(index, torch.Tensor):  # the pairs' tensors may be on an accelerator
            index = index.cpu()
        return torch.arange(len(self))[index].tolist()

    # ------------------------------------------------------------------ foregrounds
    def foreground(self, kind: Kind = "real") -> torch.Tensor:
        """(image - background) / 255 + 0.5 as float32 (N,3,S,S): the models' input, so
        one model serves every unit's background (``pixels.image_to_foreground``)."""
        owner = type(self).__name__
        if kind not in KINDS:
            raise TactileBenchError(
                f"{owner}.foreground: kind must be 'sim' or 'real', not {kind!r}"
            )
        image = getattr(self, kind)
        if image is None:
            raise TactileBenchError(f"{owner}: no {kind} images in this set")
        return image_to_foreground(image.float(), self._background(kind).float())

    def _background(self, kind: Kind) -> torch.Tensor:
        """The no-contact frame of ``kind``'s images, (3,S,S) or one a pair (N,3,S,S)."""
        frame = getattr(self, self.BACKGROUNDS[kind])
        if frame is None:
            raise TactileBenchError(f"{type(self).__name__}: no {kind} background in this set")
        return frame


def _take(value: torch.Tensor | None, index: torch.Tensor | slice) -> torch.Tensor | None:
    return None if value is None else value[index]
