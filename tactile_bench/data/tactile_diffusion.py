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

Validation (a messy folder gets a one-line error naming the file): unreadable or truncated
images, a frame with other channels or another size than the rest, a colour file without its
mask or the reverse, a file the split lists but the folder lacks, a folder that is not a
braille letter, an empty folder. Hidden files (``.DS_Store``) are ignored. Pass
``skipped=[]`` to skip bad samples instead: each skipped file is appended with its reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.sensor.depth import GelSpec

from .images import SameSize, is_hidden, read_gray, read_image
from .pairs import PairSet

REAL_BACKGROUND_ID = 10044  # the real DIGIT's no-contact frame in the release
MM_PER_LEVEL = 0.03  # TACTO's pixmm in ycb_slide_sim/config (height maps saved in these units)
LETTERS: tuple[str, ...] = tuple(c.lower() for c in CHARACTERS)
#: (file, what is wrong) of each sample skipped when the caller asked to skip bad ones
Skipped = list[tuple[str, str]]


def _label(letter: str, where: Path) -> int:
    if letter.lower() not in LETTERS:
        raise TactileBenchError(
            f"{where}: unknown braille letter folder {letter!r} (expected a-z or #)"
        )
    return LETTERS.index(letter.lower())


def _sample_error(exc: TactileBenchError, where: Path, skipped: Skipped | None) -> None:
    """Raise a per-sample problem, or record it when the caller chose to skip bad samples."""
    if skipped is None:
        raise exc
    skipped.append((str(where), str(exc)))


def _files(folder: Path) -> list[str]:
    return sorted(f.name for f in folder.iterdir() if f.is_file() and not is_hidden(f))


def _letter_dirs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and not is_hidden(p))


def read_split(path: Path) -> dict[str, dict[str, list[str]]]:
    """``files_train_test.npy``: {letter: {"train": [...], "test": [...]}} (a pickled dict)."""
    try:
        raw = np.load(path, allow_pickle=True)
        data = raw.item() if isinstance(raw, np.ndarray) and raw.dtype == object else raw
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except Exception as exc:  # np.load of arbitrary bytes: ValueError, EOFError, pickle errors
        reason = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise TactileBenchError(f"{path}: not a readable split file ({reason})") from None
    if not isinstance(data, dict):
        raise TactileBenchError(f"{path}: expected a dict letter -> {{train, test}}")
    out: dict[str, dict[str, list[str]]] = {}
    for letter, parts in data.items():
        if not isinstance(parts, dict) or not {"train", "test"} <= set(parts):
            raise TactileBenchError(f"{path}: entry {letter!r} lacks 'train'/'test' lists")
        try:
            out[str(letter)] = {k: [str(f) for f in parts[k]] for k in ("train", "test")}
        except TypeError:
            raise TactileBenchError(f"{path}: entry {letter!r}: train/test are not lists") from None
    return out


def _all_files(color_dir: Path, mask_dir: Path, skipped: Skipped | None) -> dict[str, list[str]]:
    """Every colour file with its mask; a file on one side only is unpaired."""
    files: dict[str, list[str]] = {}
    for letter_dir in _letter_dirs(color_dir):
        colors = set(_files(letter_dir))
        mask_letter = mask_dir / letter_dir.name
        masks = set(_files(mask_letter)) if mask_letter.is_dir() else set()
        for name in sorted(colors ^ masks):
            has = color_dir if name in colors else mask_dir
            lacks = mask_dir if name in colors else color_dir
            where = has / letter_dir.name / name
            exc = TactileBenchError(
                f"{where}: unpaired: no {lacks / letter_dir.name / name} with the same name"
            )
            _sample_error(exc, where, skipped)
        files[letter_dir.name] = sorted(colors & masks)
    return files


def load_braille_pairs(
    root: str | os.PathLike,
    split: str = "train",
    gel: GelSpec | None = None,
    subset: str = "real_fine_tuning",
    mm_per_level: float = MM_PER_LEVEL,
    background_id: int = REAL_BACKGROUND_ID,
    skipped: Skipped | None = None,
) -> PairSet:
    """(TACTO depth, real DIGIT frame) pairs of ``<root>/<subset>`` for ``split``.

    ``split`` is "train", "test" (from ``files_train_test.npy``) or "all" (every file in
    ``color/``). Images are area-resized to S x S like the paper; depth (mm) is the mask's
    grey level times ``mm_per_level``. ``meta["label"]`` indexes ``CHARACTERS``.
    With ``skipped`` (a list), bad samples are skipped and recorded in it instead of raising.
    """
    gel = gel or GelSpec()
    root = Path(root)
    base = root / subset
    color_dir, mask_dir = base / "color", base / "mask"
    for d in (color_dir, mask_dir):
        if not d.is_dir():
            raise TactileBenchError(f"{d}: folder not found")
    if split == "all":
        files = _all_files(color_dir, mask_dir, skipped)
    elif split in ("train", "test"):
        files = {k: v[split] for k, v in read_split(base / "files_train_test.npy").items()}
    else:
        raise TactileBenchError(
            f"load_braille_pairs: split must be train, test or all, not {split!r}"
        )
    same = SameSize("frames and masks")
    depths, reals, labels = [], [], []
    for letter, names in files.items():
        try:
            label = _label(letter, color_dir / letter)
        except TactileBenchError as exc:
            _sample_error(exc, color_dir / letter, skipped)
            continue
        for name in names:
            try:
                grey = read_gray(mask_dir / letter / name, gel.size, same)
                real = read_image(color_dir / letter / name, gel.size, same)
            except TactileBenchError as exc:
                _sample_error(exc, color_dir / letter / name, skipped)
                continue
            depths.append(torch.from_numpy((grey * mm_per_level).astype(np.float32))[None])
            reals.append(real)
            labels.append(label)
    if not depths:
        raise TactileBenchError(f"{base}: no {split!r} images")
    bg = read_image(root / "bgs" / f"bg_{background_id}.png", gel.size, same)
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
    skipped: Skipped | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The real classifier test frames ``<root>/real/color/<letter>/*``: (images, labels, bg).

    Images (N, 3, S, S) uint8, labels (N,) indexing ``CHARACTERS``, background (3, S, S).
    With ``skipped`` (a list), bad frames are skipped and recorded in it instead of raising.
    """
    gel = gel or GelSpec()
    root = Path(root)
    color_dir = root / subset / "color"
    if not color_dir.is_dir():
        raise TactileBenchError(f"{color_dir}: folder not found")
    same = SameSize()
    images, labels = [], []
    for letter_dir in _letter_dirs(color_dir):
        try:
            label = _label(letter_dir.name, letter_dir)
        except TactileBenchError as exc:
            _sample_error(exc, letter_dir, skipped)
            continue
        for name in _files(letter_dir):
            try:
                images.append(read_image(letter_dir / name, gel.size, same))
            except TactileBenchError as exc:
                _sample_error(exc, letter_dir / name, skipped)
                continue
            labels.append(label)
    if not images:
        raise TactileBenchError(f"{color_dir}: no images")
    bg = read_image(root / "bgs" / f"bg_{background_id}.png", gel.size, same)
    return torch.stack(images), torch.tensor(labels, dtype=torch.int64), bg
