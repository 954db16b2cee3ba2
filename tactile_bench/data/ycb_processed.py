"""Tactile-Diffusion's processed YCB-Slide copy: real DIGIT frames with TACTO depth beside them.

Its pretraining (``tacto_diffusion/data/dataio_ycb.py``, ``utils/misc.py`` at
carolinahiguera/Tactile-Diffusion) reads

    YCB-Slide/
      dataset/<object>/dataset_<k>/
        frames/frame_%07d.jpg            real DIGIT frames
        frames_depth/frame_%07d.jpg      TACTO heightmap of the same frame (same name)
        files_train_test.npz             np.savez(train=[names], test=[names])
      bgs/bg_<i>.jpg                     no-contact frames; object -> i is ``bgs_objects``

The heightmaps were written by ``save_hm`` (``ycb_slide_sim/modules/misc.py``): TACTO's map in
pixels of ``pixmm`` = 0.03 mm (``ycb_slide_sim/config/config.yaml``), flipped on both axes so
that it lies as the real frame does, cast to 8 bits by ``cv2.imwrite``. So a grey level is
0.03 mm, and the file is paired with the frame as stored, without another flip. The split is
the copy's own (``get_train_test_idx``: 20% of each log's frames at random, not by
trajectory). A log without its ``files_train_test.npz`` gets one drawn the same way
(:func:`make_log_split`, from a seed), written where the run writes, never into the copy, as
the braille release's split is (``tactile_diffusion.split_for_run``). Frames the mocap
cleanup removed have no heightmap (``touch_simulator.py`` deletes them from
``frames_depth``) and are left out, as the original's loader skips a frame it cannot read.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_npz
from tactile_bench.sensor.depth import GelSpec

from .corpus import CorpusPairs
from .images import is_hidden, read_image, read_mask
from .tactile_diffusion import MM_PER_LEVEL

#: ``bgs_objects`` of Tactile-Diffusion's ``utils/misc.py``: each object's background frame
BGS_OBJECTS = {
    "004_sugar_box": 0,
    "005_tomato_soup_can": 1,
    "006_mustard_bottle": 2,
    "021_bleach_cleanser": 3,
    "025_mug": 4,
    "035_power_drill": 0,
    "037_scissors": 5,
    "042_adjustable_wrench": 6,
    "048_hammer": 8,
    "055_baseball": 8,
}


def processed_root(path: str | os.PathLike) -> Path | None:
    """The processed copy's ``YCB-Slide`` folder at ``path`` (itself or its ``YCB-Slide/``
    child), or None when neither holds ``dataset/<object>/dataset_<k>/frames_depth``."""
    path = Path(path)
    for base in (path, path / "YCB-Slide"):
        if any((base / "dataset").glob("*/dataset_*/frames_depth")):
            return base
    return None


def released_background(bgs: Path, object_name: str) -> Path | None:
    """``bgs/bg_<i>.jpg`` of ``object_name`` by ``bgs_objects``, when that file exists."""
    i = BGS_OBJECTS.get(object_name)
    path = bgs / f"bg_{i}.jpg"
    return path if i is not None and path.is_file() else None


#: each log's split file, as ``get_train_test_idx`` writes it
SPLIT_FILE = "files_train_test.npz"
#: ``split_ycb_dataset``'s default: the share of a log's frames in its test list
TEST_RATIO = 0.2


def make_log_split(
    log: Path, seed: int, test_ratio: float = TEST_RATIO
) -> tuple[list[str], list[str]]:
    """``get_train_test_idx`` of Tactile-Diffusion's ``utils/misc.py`` for one log: of the
    ``.jpg`` files in ``frames/``, ``int(n * test_ratio)`` at random are test, the rest train.

    The original draws with Python's global ``random``; here a generator seeded by ``seed``
    and the log's own path (object and ``dataset_<k>``) makes each log's split repeatable
    whichever other logs are read. Files are sorted first (``listdir`` order is the
    filesystem's)."""
    frames = sorted(f.name for f in (log / "frames").glob("*.jpg") if not is_hidden(f))
    key = zlib.crc32(f"{log.parent.name}/{log.name}".encode())
    rng = np.random.default_rng([seed, key])
    test_idx = set(rng.choice(len(frames), int(len(frames) * test_ratio), replace=False).tolist())
    train = [f for i, f in enumerate(frames) if i not in test_idx]
    return train, [frames[i] for i in sorted(test_idx)]


def save_log_split(train: list[str], test: list[str], path: Path) -> Path:
    """Write a log's split as the original does (``np.savez(train=..., test=...)``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_npz(
        path, train=np.asarray(train, dtype=str), test=np.asarray(test, dtype=str)
    )


def _log_split(log: Path, seed: int, write_to: Path | None) -> tuple[list[str], list[str], bool]:
    """A log's (train, test) files: its own split file, else one drawn by
    :func:`make_log_split` (written under ``write_to/<object>/<log>/`` when given); and
    whether it was drawn."""
    if (log / SPLIT_FILE).exists():
        return (*_read_split(log / SPLIT_FILE), False)
    train, test = make_log_split(log, seed)
    if write_to is not None:
        save_log_split(train, test, write_to / log.parent.name / log.name / SPLIT_FILE)
    return train, test, True


def _read_split(path: Path) -> tuple[list[str], list[str]]:
    try:
        with np.load(path, allow_pickle=False) as z:
            return [str(f) for f in z["train"]], [str(f) for f in z["test"]]
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found (the copy's per-log split)") from None
    except KeyError as exc:
        raise TactileBenchError(f"{path}: no {exc} list (expected train and test)") from None
    except Exception as exc:  # np.load of arbitrary bytes
        reason = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise TactileBenchError(f"{path}: not a readable .npz split ({reason})") from None


def load_ycb_processed(
    root: str | os.PathLike,
    objects: Sequence[str] | None = None,
    gel: GelSpec | None = None,
    mm_per_level: float = MM_PER_LEVEL,
    stride: int = 1,
    skipped: list[tuple[str, str]] | None = None,
    seed: int = 0,
    write_splits_to: Path | None = None,
) -> tuple[CorpusPairs, dict[str, object]]:
    """(depth, real frame) pairs of the processed copy, and what was read.

    ``meta["test"]`` marks the copy's test frames; ``meta`` also has object, trajectory (one
    per log) and frame. The background of each object is its ``bgs_objects`` frame, or the
    log's first listed frame when that file is absent (said in the returned info). A log
    without its split file gets one from :func:`make_log_split` (``seed``), written to
    ``write_splits_to/<object>/dataset_<k>/files_train_test.npz`` when given.
    """
    gel = gel or GelSpec()
    base = _processed_base(root)
    data = base / "dataset"
    names = _object_names(data, objects)
    depths, reals, bgs = [], [], []
    meta: dict[str, list[int]] = {"object": [], "trajectory": [], "frame": [], "test": []}
    bg_index: list[int] = []
    no_depth, sources = 0, {}
    generated: list[str] = []
    trajectory = 0
    for o, name in enumerate(names):
        logs = sorted(
            (d for d in (data / name).glob("dataset_*") if d.is_dir()),
            key=lambda d: (len(d.name), d.name),
        )
        released = released_background(base / "bgs", name)
        for log in logs:
            train, test, drawn = _log_split(log, seed, write_splits_to)
            generated += [f"{name}/{log.name}"] if drawn else []
            listed = [(f, 0) for f in train] + [(f, 1) for f in test]
            listed = sorted(listed)[::stride]
            read, missing = _read_listed(log, listed, gel, mm_per_level, skipped)
            no_depth += missing
            for f, is_test, depth, real in read:
                depths.append(depth)
                reals.append(real)
                meta["object"].append(o)
                meta["trajectory"].append(trajectory)
                meta["frame"].append(int("".join(c for c in f if c.isdigit()) or 0))
                meta["test"].append(is_test)
            if read:
                first = log / "frames" / listed[0][0]
                bg, sources[name] = _log_background(base, released, first, gel)
                bgs.append(bg)
                bg_index += [len(bgs) - 1] * len(read)
            trajectory += 1
    if not depths:
        raise TactileBenchError(f"{data}: no (frame, frames_depth) pairs")
    pairs = CorpusPairs(
        depth=torch.stack(depths),
        real=torch.stack(reals),
        real_background=torch.stack(bgs),
        real_bg_index=torch.tensor(bg_index),
        meta={k: np.asarray(v, dtype=np.int64) for k, v in meta.items()},
    )
    info: dict[str, object] = {
        "root": str(base),
        "objects": names,
        "listed_without_depth": no_depth,
        "backgrounds": sources,
        "mm_per_level": mm_per_level,
        "splits": (
            f"generated for {len(generated)} of {trajectory} logs (seed {seed}, test "
            f"{TEST_RATIO}): {', '.join(generated)}"
            if generated
            else f"each log's {SPLIT_FILE}"
        ),
    }
    return pairs, info


def _processed_base(root: str | os.PathLike) -> Path:
    """The copy's ``YCB-Slide`` folder under ``root``: anything else is refused up front."""
    base = processed_root(root)
    if base is None:
        raise TactileBenchError(
            f"{root}: not Tactile-Diffusion's YCB-Slide copy (expected "
            "dataset/<object>/dataset_<k>/{frames,frames_depth}/ in it or in its YCB-Slide/)"
        )
    return base


def _object_names(data: Path, objects: Sequence[str] | None) -> list[str]:
    """The object folders to read, sorted: all, or ``objects``, each of which must be there."""
    names = sorted(
        p.name for p in data.iterdir() if p.is_dir() and not is_hidden(p)
    )  # the original skips the .zip/.sh files beside them
    if objects is not None:
        missing = sorted(set(objects) - set(names))
        if missing:
            raise TactileBenchError(f"{data}: no folder for objects {missing}")
        names = [n for n in names if n in objects]
    return names


def _read_listed(
    log: Path,
    listed: list[tuple[str, int]],
    gel: GelSpec,
    mm_per_level: float,
    skipped: list[tuple[str, str]] | None,
) -> tuple[list[tuple[str, int, torch.Tensor, torch.Tensor]], int]:
    """A log's (file, is test, depth in mm, frame) pairs, and how many had no heightmap."""
    read, no_depth = [], 0
    for f, is_test in listed:
        if not (log / "frames_depth" / f).is_file():
            no_depth += 1  # a mocap glitch touch_simulator.py removed
            continue
        try:
            depth = read_mask(log / "frames_depth" / f, gel.size, weights_bgr_as_rgb=False)
            real = read_image(log / "frames" / f, gel.size)
        except TactileBenchError as exc:
            if skipped is None:
                raise
            skipped.append((str(log / "frames" / f), str(exc)))
            continue
        depth_mm = torch.from_numpy((depth * mm_per_level).astype(np.float32))[None]
        read.append((f, is_test, depth_mm, real))
    return read, no_depth


def _log_background(
    base: Path, released: Path | None, first: Path, gel: GelSpec
) -> tuple[torch.Tensor, str]:
    """A log's background and where it came from: the released frame, else its first frame."""
    if released is not None:
        return read_image(released, gel.size), str(released.relative_to(base))
    return read_image(first, gel.size), "first frame of each log (no bgs/bg_<i>.jpg)"
