"""Loader for the braille data in the layout of the Tactile-Diffusion release.

The release (carolinahiguera/Tactile-Diffusion, ``datasets/braille``) is laid out as its
``tacto_diffusion/utils/misc.py`` and ``braille_clf`` configs read it:

    braille/
      real_fine_tuning/
        color/<letter>/<file>          real DIGIT frames of the fine-tuning contacts
        mask/<letter>/<file>           TACTO depth of the same contact, same file name
        files_train_test.npy           (optional) np.save of {letter: {"train": [...], ...}}
      real/color/<letter>/<file>       real frames of the classifier's test set (no depth)
      sim_tacto/color/<letter>/<file>  TACTO frames the paper's Sim row trained on
      bgs/bg_<id>.png                  no-contact frames (10044: the real DIGIT; 11/12: sim)

Letters are ``a``..``z`` and ``#``. TACTO's height maps are written in units of its ``pixmm``
(0.03 mm a grey level), which is our default scale.

The split file is not part of a fresh release: ``train_braille.py`` writes it at every run
(``split_braille_dataset``). When it is absent, ``make_split`` draws one the same way from a
seed, and the caller writes it where its run writes, never into the dataset.

As the original reads them (``dataio_braille.py``): a mask is any image, converted to grey,
resized to the model size on its own; a frame is subtracted from its background at full size
(``compute_diff``) before resizing, so frames must have the background's size.

Validation (a messy folder gets a one-line error naming the file): unreadable or truncated
images, a frame of another size than its background, a colour file without its mask or the
reverse, a file the split lists but the folder lacks, a folder that is not a braille letter,
an empty folder. Hidden files (``.DS_Store``) are ignored. Pass ``skipped=[]`` to skip bad
samples instead: each skipped file is appended with its reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.guard.images import open_image
from tactile_bench.sensor.depth import GelSpec

from .corpus import CorpusPairs
from .images import SameSize, is_hidden, read_image, read_mask

REAL_BACKGROUND_ID = 10044  # the real DIGIT's no-contact frame in the release
SIM_BACKGROUND_ID = 11  # braille_clf/data/dataio.py: bg_11 under sim_tacto training
#: config_braille.json: the diffusion translator's split is 20% of the files, 80/20 train/test
DATASET_RATIO = 0.2
TEST_RATIO = 0.2
SPLIT_FILE = "files_train_test.npy"
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


def _background_size(bg_path: Path) -> SameSize:
    """Frames must have their background's size: the original subtracts it at full size
    (``compute_diff`` in ``dataio_braille.py`` and ``braille_clf``), which fails otherwise."""
    same = SameSize("frames and their background (subtracted before resizing, as the original)")
    same.check(bg_path, open_image(bg_path).size)
    return same


def _files(folder: Path) -> list[str]:
    return sorted(f.name for f in folder.iterdir() if f.is_file() and not is_hidden(f))


def _letter_dirs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and not is_hidden(p))


def braille_root(source: str | os.PathLike) -> Path:
    """The braille folder of a ``source:``: the folder itself or its ``braille/`` child.

    The release unpacks to ``datasets/braille``; users point at either. One rule for
    ``check``, ``diagnose`` and every stage, so all accept the same paths.
    """
    path = Path(source)
    for base in (path, path / "braille"):
        if (base / "real_fine_tuning").is_dir():
            return base
    raise TactileBenchError(
        f"{path}: not a Tactile-Diffusion braille folder (expected {path}/real_fine_tuning/ "
        f"or {path}/braille/real_fine_tuning/)"
    )


Split = dict[str, dict[str, list[str]]]


def make_split(
    root: str | os.PathLike,
    seed: int,
    dataset_ratio: float = DATASET_RATIO,
    test_ratio: float = TEST_RATIO,
) -> Split:
    """``split_braille_dataset`` of Tactile-Diffusion's ``utils/misc.py``, from ``seed``.

    Per letter (``bgs_letters``: a..z, #) over the files of ``mask/<letter>``: shuffle, keep
    ``int(n * dataset_ratio)`` of them, ``int(kept * (1 - test_ratio))`` of those train and
    the rest test. The original draws from Python's and NumPy's global generators; here one
    seeded generator makes it repeatable. Files are sorted first (glob order is the
    filesystem's).
    """
    mask_dir = Path(root) / "real_fine_tuning" / "mask"
    if not mask_dir.is_dir():
        raise TactileBenchError(f"{mask_dir}: folder not found")
    rng = np.random.default_rng(seed)
    out: Split = {}
    for letter in LETTERS:
        folder = mask_dir / letter
        files = _files(folder) if folder.is_dir() else []
        files = [files[i] for i in rng.permutation(len(files))]
        kept = rng.choice(len(files), size=int(len(files) * dataset_ratio), replace=False)
        files = [files[i] for i in kept]
        train = rng.choice(len(files), size=int(len(files) * (1 - test_ratio)), replace=False)
        test = sorted(set(range(len(files))) - set(train.tolist()))
        out[letter] = {"train": [files[i] for i in train], "test": [files[i] for i in test]}
    return out


def save_split(split: Split, path: Path) -> Path:
    """Write ``split`` as the original does (``np.save`` of the dict), atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.save(f, np.array(split, dtype=object), allow_pickle=True)
    os.replace(tmp, path)
    return path


def split_for_run(
    root: str | os.PathLike,
    seed: int,
    write_to: Path | None = None,
    dataset_ratio: float = DATASET_RATIO,
    test_ratio: float = TEST_RATIO,
) -> tuple[Split, str]:
    """The release's split file when present, else ``make_split`` (written to ``write_to``).

    Returns (split, where it came from: the file's path, or "generated (seed N)").
    """
    path = Path(root) / "real_fine_tuning" / SPLIT_FILE
    if path.exists():
        return read_split(path), str(path)
    split = make_split(root, seed, dataset_ratio, test_ratio)
    if write_to is not None:
        save_split(split, write_to)
    return split, f"generated (seed {seed}, ratio {dataset_ratio}, test {test_ratio})"


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
    split: str | Split = "train",
    gel: GelSpec | None = None,
    subset: str = "real_fine_tuning",
    mm_per_level: float = MM_PER_LEVEL,
    background_id: int = REAL_BACKGROUND_ID,
    skipped: Skipped | None = None,
) -> CorpusPairs:
    """(TACTO depth, real DIGIT frame) pairs of ``<root>/<subset>`` for ``split``.

    ``split`` is "train", "test" (from ``files_train_test.npy``), "all" (every file in
    ``color/``), or a split of its own ({letter: [names]}, e.g. a ``make_split`` part).
    Frames, masks and the background are area-resized to S x S each on its own, like the
    paper; depth (mm) is the mask's grey level times ``mm_per_level``.
    ``meta["label"]`` indexes ``CHARACTERS``; ``meta["file"]`` is ``<letter>/<name>``.
    With ``skipped`` (a list), bad samples are skipped and recorded in it instead of raising.
    """
    gel = gel or GelSpec()
    root = Path(root)
    base = root / subset
    color_dir, mask_dir = base / "color", base / "mask"
    for d in (color_dir, mask_dir):
        if not d.is_dir():
            raise TactileBenchError(f"{d}: folder not found")
    if isinstance(split, dict):
        files = {str(k): list(v) for k, v in split.items()}
    elif split == "all":
        files = _all_files(color_dir, mask_dir, skipped)
    elif split in ("train", "test"):
        files = {k: v[split] for k, v in read_split(base / SPLIT_FILE).items()}
    else:
        raise TactileBenchError(
            f"load_braille_pairs: split must be train, test or all, not {split!r}"
        )
    if not any(files.values()):
        what = "split" if isinstance(split, dict) else repr(split)
        raise TactileBenchError(f"{base}: no {what} images")
    bg_path = root / "bgs" / f"bg_{background_id}.png"
    same = _background_size(bg_path)
    bg = read_image(bg_path, gel.size)
    depths, reals, labels, read = [], [], [], []
    for letter, names in files.items():
        try:
            label = _label(letter, color_dir / letter)
        except TactileBenchError as exc:
            _sample_error(exc, color_dir / letter, skipped)
            continue
        for name in names:
            try:
                grey = read_mask(mask_dir / letter / name, gel.size)
                real = read_image(color_dir / letter / name, gel.size, same)
            except TactileBenchError as exc:
                _sample_error(exc, color_dir / letter / name, skipped)
                continue
            depths.append(torch.from_numpy((grey * mm_per_level).astype(np.float32))[None])
            reals.append(real)
            labels.append(label)
            read.append(f"{letter}/{name}")
    if not depths:
        what = "split" if isinstance(split, dict) else repr(split)
        raise TactileBenchError(f"{base}: no {what} images")
    n = len(depths)
    return CorpusPairs(
        depth=torch.stack(depths),
        real=torch.stack(reals),
        real_background=bg,
        real_bg_index=torch.zeros(n, dtype=torch.int64),
        meta={"label": np.asarray(labels, dtype=np.int64), "file": np.asarray(read)},
    )


def load_braille_real_images(
    root: str | os.PathLike,
    gel: GelSpec | None = None,
    subset: str = "real",
    background_id: int = REAL_BACKGROUND_ID,
    skipped: Skipped | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The frames ``<root>/<subset>/color/<letter>/*``: (images, labels, background).

    ``subset`` "real": the classifier's real test frames (background ``bg_10044``);
    "sim_tacto" with ``background_id`` 11: the TACTO frames of the paper's Sim row.
    Images (N, 3, S, S) uint8, labels (N,) indexing ``CHARACTERS``, background (3, S, S).
    With ``skipped`` (a list), bad frames are skipped and recorded in it instead of raising.
    """
    gel = gel or GelSpec()
    root = Path(root)
    color_dir = root / subset / "color"
    if not color_dir.is_dir():
        raise TactileBenchError(f"{color_dir}: folder not found")
    bg_path = root / "bgs" / f"bg_{background_id}.png"
    same = _background_size(bg_path)
    bg = read_image(bg_path, gel.size)
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
    return torch.stack(images), torch.tensor(labels, dtype=torch.int64), bg
