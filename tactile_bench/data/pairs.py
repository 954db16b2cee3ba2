"""Paired (sim depth, real image) data from sliding logs, kept in shards on disk.

``BrailleSet`` holds one contact protocol with a single background per sensor; sliding
corpora differ: many trajectories, one background per recording (a real DIGIT's unit and
lighting drift between logs), per-frame metadata (press, sliding velocity, time), and a
train/test split by trajectory. A ``PairSet`` carries the same array names as ``BrailleSet``
(``depth``, ``sim``, ``real``, ``foreground``) so the translators' code reads either.

On disk: ``<root>/manifest.json`` lists shards ``shards/<name>.npz`` (one trajectory each,
written atomically, content hash recorded) and ``backgrounds.npz``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from tactile_bench.data.pixels import image_to_foreground, to_uint8
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_npz, file_sha256, load_npz

FORMAT = 1
SPLITS = ("train", "test", "all")


@dataclass
class PairSet:
    """N pairs: ``depth`` (N,1,S,S) mm, ``real`` (N,3,S,S) uint8, optional ``sim`` likewise.

    ``real_background`` (B,3,S,S) uint8 holds the no-contact frames, ``real_bg_index`` (N,)
    says which one each pair was recorded with. ``meta`` maps names to per-pair arrays.
    """

    depth: torch.Tensor
    real: torch.Tensor
    real_background: torch.Tensor
    real_bg_index: torch.Tensor
    sim: torch.Tensor | None = None
    sim_background: torch.Tensor | None = None
    meta: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.depth)
        if self.depth.dim() != 4 or self.depth.shape[1] != 1:
            raise TactileBenchError(
                f"PairSet: depth must be (N,1,S,S), got {tuple(self.depth.shape)}"
            )
        size = tuple(self.depth.shape[2:])
        if tuple(self.real.shape) != (n, 3, *size):
            raise TactileBenchError(
                f"PairSet: real must be {(n, 3, *size)}, got {tuple(self.real.shape)}"
            )
        if self.sim is not None and tuple(self.sim.shape) != (n, 3, *size):
            raise TactileBenchError(
                f"PairSet: sim must be {(n, 3, *size)}, got {tuple(self.sim.shape)}"
            )
        if self.real_background.dim() == 3:
            self.real_background = self.real_background[None]
        if tuple(self.real_background.shape[1:]) != (3, *size):
            raise TactileBenchError("PairSet: real_background must be (B,3,S,S) like depth")
        self.real_bg_index = torch.as_tensor(self.real_bg_index, dtype=torch.int64).reshape(-1)
        if len(self.real_bg_index) != n:
            raise TactileBenchError("PairSet: real_bg_index must have one entry per pair")
        if n and (
            self.real_bg_index.min() < 0 or self.real_bg_index.max() >= len(self.real_background)
        ):
            raise TactileBenchError("PairSet: real_bg_index outside the backgrounds")
        for k, v in self.meta.items():
            if len(v) != n:
                raise TactileBenchError(f"PairSet: meta {k!r} has {len(v)} entries for {n} pairs")
        if not torch.isfinite(self.depth).all():
            raise TactileBenchError("PairSet: depth has NaN or infinite values")
        if n and float(self.depth.min()) < 0:
            raise TactileBenchError(
                f"PairSet: negative depth ({float(self.depth.min()):.3g} mm); depth is the "
                "gel's penetration, >= 0"
            )

    def __len__(self) -> int:
        return len(self.depth)

    def background(self, kind: Literal["sim", "real"] = "real") -> torch.Tensor:
        """(N,3,S,S) uint8 no-contact frame of every pair."""
        if kind == "real":
            return self.real_background[self.real_bg_index]
        if self.sim_background is None:
            raise TactileBenchError("PairSet: no sim images in this set")
        return self.sim_background.expand(len(self), -1, -1, -1)

    def foreground(self, kind: Literal["sim", "real"] = "real") -> torch.Tensor:
        """(image - background) / 255 + 0.5 as float32 (N,3,S,S): the models' input."""
        if kind not in ("sim", "real"):
            raise TactileBenchError(
                f"PairSet.foreground: kind must be 'sim' or 'real', not {kind!r}"
            )
        image = self.real if kind == "real" else self.sim
        if image is None:
            raise TactileBenchError("PairSet: no sim images in this set")
        return image_to_foreground(image.float(), self.background(kind).float())

    def subset(self, idx: torch.Tensor | slice | Sequence[int]) -> PairSet:
        """The pairs at ``idx`` (indices, mask or slice); backgrounds are shared."""
        if not isinstance(idx, slice):
            idx = torch.as_tensor(idx)
            idx = idx if idx.dtype == torch.bool else idx.long()
        np_idx = idx if isinstance(idx, slice) else idx.numpy()
        return PairSet(
            depth=self.depth[idx],
            real=self.real[idx],
            real_background=self.real_background,
            real_bg_index=self.real_bg_index[idx],
            sim=None if self.sim is None else self.sim[idx],
            sim_background=self.sim_background,
            meta={k: v[np_idx] for k, v in self.meta.items()},
        )

    @classmethod
    def cat(cls, parts: Sequence[PairSet]) -> PairSet:
        """Concatenate sets that share their backgrounds (as the shards of one corpus do)."""
        if not parts:
            raise TactileBenchError("PairSet.cat: nothing to concatenate")
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
    ) -> PairSet:
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


def load_pairs(root: str | os.PathLike, split: str = "train", verify: bool = False) -> PairSet:
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
        parts.append(PairSet.load_shard(path, real_bg, sim_bg))
    if not parts:
        raise TactileBenchError(f"{root}: no {split!r} pairs in the manifest")
    return PairSet.cat(parts)
