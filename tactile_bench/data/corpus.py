"""A corpus of (depth, real image) pairs from many recordings, kept in shards on disk.

``BrailleSet`` holds one contact protocol with a single background per sensor; a corpus
differs: many trajectories or logs, one background per recording (a real DIGIT's unit and
lighting drift between logs), per-frame metadata (press, sliding velocity, time), and a
train/test split by trajectory. ``CorpusPairs`` is its in-memory form, a ``data.paired.Pairs``
like ``BrailleSet`` (``depth``, ``sim``, ``real``, ``foreground``), so the translators' code
reads either.

On disk: ``<root>/manifest.json`` lists shards ``shards/<name>.npz`` (one trajectory each,
written atomically, content hash recorded) and ``backgrounds.npz``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch

from tactile_bench.data.paired import Pairs, shape_error
from tactile_bench.data.pixels import to_uint8
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_npz, file_sha256, load_npz

FORMAT = 1
SPLITS = ("train", "test", "all")


@dataclass
class CorpusPairs(Pairs):
    """N pairs: ``depth`` (N,1,S,S) mm, ``real`` (N,3,S,S) uint8, optional ``sim`` likewise.

    ``real_background`` (B,3,S,S) uint8 holds the no-contact frames, ``real_bg_index`` (N,)
    says which one each pair was recorded with. ``meta`` maps names to per-pair arrays.
    Shape checks, ``subset`` and ``foreground`` are ``data.paired.Pairs``'s; the stacked
    backgrounds, depth's values, shards and ``cat`` are this class's own.
    """

    PER_PAIR: ClassVar[tuple[str, ...]] = ("depth", "sim", "real", "real_bg_index")
    FRAMES: ClassVar[tuple[str, ...]] = ("sim_background",)  # real_background: (B,3,S,S)
    OPTIONAL: ClassVar[frozenset[str]] = frozenset({"sim", "sim_background"})

    depth: torch.Tensor
    real: torch.Tensor
    real_background: torch.Tensor
    real_bg_index: torch.Tensor
    sim: torch.Tensor | None = None
    sim_background: torch.Tensor | None = None
    meta: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.real_background.dim() == 3:
            self.real_background = self.real_background[None]
        self.real_bg_index = torch.as_tensor(self.real_bg_index, dtype=torch.int64).reshape(-1)
        self._check_pairs(**{f"meta {k!r}": v for k, v in self.meta.items()})
        n, size = len(self), tuple(self.depth.shape[2:])
        bgs = self.real_background
        if bgs.dim() != 4 or tuple(bgs.shape[1:]) != (3, *size):
            raise shape_error(type(self).__name__, "real_background", "(B,3,S,S)", bgs.shape)
        if n and (self.real_bg_index.min() < 0 or self.real_bg_index.max() >= len(bgs)):
            raise TactileBenchError("CorpusPairs: real_bg_index outside the backgrounds")
        if not torch.isfinite(self.depth).all():
            raise TactileBenchError("CorpusPairs: depth has NaN or infinite values")
        if n and float(self.depth.min()) < 0:
            raise TactileBenchError(
                f"CorpusPairs: negative depth ({float(self.depth.min()):.3g} mm); depth is the "
                "gel's penetration, >= 0"
            )

    def background(self, kind: Literal["sim", "real"] = "real") -> torch.Tensor:
        """(N,3,S,S) uint8 no-contact frame of every pair."""
        if kind == "real":
            return self.real_background[self.real_bg_index]
        if self.sim_background is None:
            raise TactileBenchError("CorpusPairs: no sim images in this set")
        return self.sim_background.expand(len(self), -1, -1, -1)

    def _background(self, kind: Literal["sim", "real"]) -> torch.Tensor:
        return self.background(kind)  # each pair's own frame, for ``foreground``

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        at = index if isinstance(index, slice) else index.numpy()
        return {"meta": {k: v[at] for k, v in self.meta.items()}}

    @classmethod
    def cat(cls, parts: Sequence[CorpusPairs]) -> CorpusPairs:
        """Concatenate sets that share their backgrounds (as the shards of one corpus do)."""
        if not parts:
            raise TactileBenchError("CorpusPairs.cat: nothing to concatenate")
        first = parts[0]
        has_sim = first.sim is not None
        return cls(
            depth=torch.cat([p.depth for p in parts]),
            real=torch.cat([p.real for p in parts]),
            real_background=first.real_background,
            real_bg_index=torch.cat([p.real_bg_index for p in parts]),
            sim=torch.cat([p.sim for p in parts]) if has_sim else None,  # type: ignore[misc]
            sim_background=first.sim_background,
            meta={k: np.concatenate([p.meta[k] for p in parts]) for k in first.meta},
        )

    # ------------------------------------------------------------------ shards
    def save_shard(self, path: str | os.PathLike) -> Path:
        """The per-pair arrays of this set as one .npz, written atomically (no backgrounds)."""
        arrays: dict[str, Any] = {
            "depth": self.depth.float().numpy(),
            "real": to_uint8(self.real).numpy(),
            "real_bg_index": self.real_bg_index.numpy(),
        }
        if self.sim is not None:
            arrays["sim"] = to_uint8(self.sim).numpy()
        arrays.update({f"meta_{k}": np.asarray(v) for k, v in self.meta.items()})
        return atomic_write_npz(Path(path), **arrays)

    @classmethod
    def load_shard(
        cls,
        path: str | os.PathLike,
        real_background: torch.Tensor,
        sim_background: torch.Tensor | None = None,
    ) -> CorpusPairs:
        """Read a shard written by ``save_shard``; bad files are a ``TactileBenchError``."""
        path = Path(path)
        base = load_npz(path, ("depth", "real", "real_bg_index"))
        try:
            with np.load(path, allow_pickle=False) as z:
                names = list(z.files)
                extra = {k: z[k] for k in names if k == "sim" or k.startswith("meta_")}
        except Exception as exc:  # a damaged member the first read did not touch
            raise TactileBenchError(f"{path}: corrupt or truncated ({exc})") from None
        try:
            return cls(
                depth=torch.from_numpy(base["depth"]).float(),
                real=to_uint8(torch.from_numpy(base["real"])),
                real_background=real_background,
                real_bg_index=torch.from_numpy(base["real_bg_index"]),
                sim=to_uint8(torch.from_numpy(extra["sim"])) if "sim" in extra else None,
                sim_background=sim_background,
                meta={k[5:]: v for k, v in extra.items() if k.startswith("meta_")},
            )
        except TactileBenchError as exc:
            raise TactileBenchError(f"{path}: {exc}") from None


def write_backgrounds(root: Path, real: torch.Tensor, sim: torch.Tensor | None) -> Path:
    """``<root>/backgrounds.npz``: real (B,3,S,S) and optionally sim (3,S,S), uint8."""
    arrays = {"real": to_uint8(real if real.dim() == 4 else real[None]).numpy()}
    if sim is not None:
        arrays["sim"] = to_uint8(sim).numpy()
    return atomic_write_npz(root / "backgrounds.npz", **arrays)


def read_manifest(root: str | os.PathLike) -> dict[str, Any]:
    """The corpus manifest, or a ``TactileBenchError`` naming the file."""
    path = Path(root) / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except (OSError, ValueError) as exc:
        raise TactileBenchError(f"{path}: not a readable manifest ({exc})") from None
    if (
        not isinstance(manifest, dict)
        or manifest.get("format") != FORMAT
        or "shards" not in manifest
    ):
        raise TactileBenchError(f"{path}: not a pair-set manifest of format {FORMAT}")
    return manifest


def load_pairs(root: str | os.PathLike, split: str = "train", verify: bool = False) -> CorpusPairs:
    """The pairs of ``split`` ("train", "test" or "all") of a corpus written by a builder.

    ``verify`` re-hashes every shard against the manifest (slow; the loaders already catch
    truncated or corrupt files).
    """
    if split not in SPLITS:
        raise TactileBenchError(f"load_pairs: split must be one of {SPLITS}, not {split!r}")
    root = Path(root)
    manifest = read_manifest(root)
    bgs = load_npz(root / "backgrounds.npz", ("real",))
    real_bg = torch.from_numpy(bgs["real"])
    sim_bg = None
    with np.load(root / "backgrounds.npz") as z:
        if "sim" in z.files:
            sim_bg = torch.from_numpy(z["sim"])
    parts = []
    for shard in manifest["shards"]:
        if not isinstance(shard, dict) or not {"file", "split"} <= set(shard):
            raise TactileBenchError(f"{root / 'manifest.json'}: a shard entry lacks file/split")
        if split != "all" and shard["split"] != split:
            continue
        path = root / str(shard["file"])
        if verify and path.is_file() and file_sha256(path) != shard.get("sha256"):
            raise TactileBenchError(f"{path}: content does not match the manifest")
        parts.append(CorpusPairs.load_shard(path, real_bg, sim_bg))
    pairs = CorpusPairs.cat(parts) if parts else None
    if pairs is None or not len(pairs):
        raise TactileBenchError(f"{root}: no {split!r} pairs in the manifest")
    return pairs
