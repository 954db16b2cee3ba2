"""Loader for the braille data in the layout of the Tactile-Diffusion release.

The release (carolinahiguera/Tactile-Diffusion, ``datasets/braille``) is laid out as its
``tacto_diffusion/utils/misc.py`` and ``braille_clf`` configs read it:

    braille/
      real_fine_tuning/
        color/<letter>/<file>          real DIGIT frames of the fine-tuning contacts
        mask/<letter>/<file>           TACTO depth of the same contact, same file name
        files_train_test.npy           np.save of {letter: {"train": [names], "test": [names]}}
      real/color/<letter>/<file>       real frames of the classifier's test set (no depth)
      bgs/bg_<id>.png                  no-contact frames (10044: the real DIGIT; 11/12: sim)

Letters are ``a``..``z`` and ``#``. The depth images are 8-bit grey; TACTO's height maps are
written in units of its ``pixmm`` (0.03 mm a grey level), which is our default scale.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.sensor.depth import GelSpec

from .pairs import PairSet
from .ycb_slide import read_gray, read_image

REAL_BACKGROUND_ID = 10044  # the real DIGIT's no-contact frame in the release
MM_PER_LEVEL = 0.03  # TACTO's pixmm in ycb_slide_sim/config (height maps saved in these units)
LETTERS: tuple[str, ...] = tuple(c.lower() for c in CHARACTERS)


def _label(letter: str, where: Path) -> int:
    if letter.lower() not in LETTERS:
        raise TactileBenchError(f"{where}: unknown braille letter folder {letter!r}")
    return LETTERS.index(letter.lower())


def read_split(path: Path) -> dict[str, dict[str, list[str]]]:
    """``files_train_test.npy``: {letter: {"train": [...], "test": [...]}} (a pickled dict)."""
    try:
        raw = np.load(path, allow_pickle=True)
        data = raw.item() if isinstance(raw, np.ndarray) and raw.dtype == object else raw
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except (OSError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        raise TactileBenchError(f"{path}: not a readable split file ({exc})") from None
    if not isinstance(data, dict):
        raise TactileBenchError(f"{path}: expected a dict letter -> {{train, test}}")
    out: dict[str, dict[str, list[str]]] = {}
    for letter, parts in data.items():
        if not isinstance(parts, dict) or not {"train", "test"} <= set(parts):
            raise TactileBenchError(f"{path}: entry {letter!r} lacks 'train'/'test' lists")
        out[str(letter)] = {k: [str(f) for f in parts[k]] for k in ("train", "test")}
    return out


def load_braille_pairs(
    root: str | os.PathLike,
    split: str = "train",
    gel: GelSpec | None = None,
    subset: str = "real_fine_tuning",
    mm_per_level: float = MM_PER_LEVEL,
    background_id: int = REAL_BACKGROUND_ID,
) -> PairSet:
    """(TACTO depth, real DIGIT frame) pairs of ``<root>/<subset>`` for ``split``.

    ``split`` is "train", "test" (from ``files_train_test.npy``) or "all" (every file in
    ``color/``). Images are area-resized to S x S like the paper; depth (mm) is the mask's
    grey level times ``mm_per_level``. ``meta["label"]`` indexes ``CHARACTERS``.
    """
    gel = gel or GelSpec()
    root = Path(root)
    base = root / subset
    color_dir, mask_dir = base / "color", base / "mask"
    for d in (color_dir, mask_dir):
        if not d.is_dir():
            raise TactileBenchError(f"{d}: folder not found")
    if split == "all":
        files = {
            p.name: sorted(f.name for f in p.iterdir() if f.is_file())
            for p in sorted(color_dir.iterdir())
            if p.is_dir()
        }
    elif split in ("train", "test"):
        files = {k: v[split] for k, v in read_split(base / "files_train_test.npy").items()}
    else:
        raise TactileBenchError(
            f"load_braille_pairs: split must be train, test or all, not {split!r}"
        )
    depths, reals, labels = [], [], []
    for letter, names in files.items():
        label = _label(letter, color_dir / letter)
        for name in names:
            grey = read_gray(mask_dir / letter / name, gel.size)
            depth = grey * mm_per_level
            if not np.isfinite(depth).all():
                raise TactileBenchError(f"{mask_dir / letter / name}: NaN depth")
            depths.append(torch.from_numpy(depth.astype(np.float32))[None])
            reals.append(read_image(color_dir / letter / name, gel.size))
            labels.append(label)
    if not depths:
        raise TactileBenchError(f"{base}: no {split!r} images")
    bg = read_image(root / "bgs" / f"bg_{background_id}.png", gel.size)
    n = len(depths)
    return PairSet(
        depth=torch.stack(depths),
        real=torch.stack(reals),
        real_background=bg,
        real_bg_index=torch.zeros(n, dtype=torch.int64),
        meta={"label": np.asarray(labels, dtype=np.int64)},
    )


def load_braille_real_images(
    root: str | os.PathLike,
    gel: GelSpec | None = None,
    subset: str = "real",
    background_id: int = REAL_BACKGROUND_ID,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The real classifier test frames ``<root>/real/color/<letter>/*``: (images, labels, bg).

    Images (N, 3, S, S) uint8, labels (N,) indexing ``CHARACTERS``, background (3, S, S).
    """
    gel = gel or GelSpec()
    root = Path(root)
    color_dir = root / subset / "color"
    if not color_dir.is_dir():
        raise TactileBenchError(f"{color_dir}: folder not found")
    images, labels = [], []
    for letter_dir in sorted(p for p in color_dir.iterdir() if p.is_dir()):
        label = _label(letter_dir.name, letter_dir)
        for f in sorted(p for p in letter_dir.iterdir() if p.is_file()):
            images.append(read_image(f, gel.size))
            labels.append(label)
    if not images:
        raise TactileBenchError(f"{color_dir}: no images")
    bg = read_image(root / "bgs" / f"bg_{background_id}.png", gel.size)
    return torch.stack(images), torch.tensor(labels, dtype=torch.int64), bg
