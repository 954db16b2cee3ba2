"""Paired sim/real data, the diagnosis's only input.

Layout on disk (documented in docs/diagnosis.md)::

    <root>/depth/<label>/<name>.png   16-bit grey, gel penetration in micrometres
    <root>/sim/<label>/<name>.png     8-bit RGB, the simulator's image of that contact
    <root>/real/<label>/<name>.png    8-bit RGB, the real sensor's image of it
    <root>/background.png             the real sensor's no-contact frame
    <root>/sim_background.png         optional: the simulator's no-contact frame
    <root>/gel.json                   optional: {"width_mm": W, "height_mm": H}, the view
                                      the images cover (default: a DIGIT's 18 x 24)

The diagnosis works on square S x S images over that view (pixels are then not square in
mm, as ``GelSpec`` has them). Each part's frames (depth, sim, real) share one size, and the
no-contact frames their side's. Each frame is resized on its own to S x S, as the
Tactile-Diffusion code resizes its frames and masks: S = ``size``, or min(64, shortest
side), so frames that are all one square size up to 64 are used as they are.

``<label>/`` may be absent (unlabelled data: files directly under depth/, sim/, real/).
Labels that are not safe folder names are encoded (``label_to_dir``): ``#`` is written as
``number_sign``, any other unsafe character percent-encoded (``/`` -> ``%2F``).

``load_paired`` also reads the Tactile-Diffusion braille release
(``<root>/real_fine_tuning/{color,mask}/<letter>/``, ``<root>/bgs/``), which has no sim
images: those are rendered with the noise-free simulator from its depth.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import unicodedata
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar
from urllib.parse import quote, unquote

import numpy as np
import torch
from PIL import Image, UnidentifiedImageError

from tactile_bench.data.corpus import CorpusPairs
from tactile_bench.data.images import area_resized
from tactile_bench.data.paired import Pairs
from tactile_bench.data.pixels import to_uint8
from tactile_bench.data.tactile_diffusion import braille_root
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.args import BYTES_PER_PAIR_PIXEL, MAX_SIZE, MIN_SIZE
from tactile_bench.guard.images import MIN_SIDE, open_header
from tactile_bench.guard.limits import check_memory
from tactile_bench.io import atomic_folder
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.press_grounding import sim_render

log = logging.getLogger(__name__)

#: labels written under another folder name (the number sign is awkward in shells and URLs)
NAMED_LABEL_DIRS: dict[str, str] = {"#": "number_sign"}
_DIR_LABELS = {v: k for k, v in NAMED_LABEL_DIRS.items()}
PARTS = ("depth", "sim", "real")
UM_PER_MM = 1000.0
LAYOUTS = ("paired", "tactile_diffusion")
DIGIT_GEL_MM = (18.0, 24.0)  # what a folder without gel.json is taken to show
GEL_FILE = "gel.json"
MAX_GEL_MM = 500.0
#: the deepest penetration a depth image may hold: a DIGIT's gel is about 2 mm thick, a
#: GelSight's a few mm; 65 mm is a unit mistake (mm written where micrometres belong)
MAX_PENETRATION_MM = 5.0
DEFAULT_SIDE = 64  # the paper's image size, the one the diagnosis is validated at
#: |log| of the ratio of a frame's proportions to the gel view's above which they disagree:
#: 10%, more than a cropped border, far less than a 3:4 frame turned a quarter (78%)
MAX_ASPECT_LOG_RATIO = math.log(1.1)


@dataclass
class DiagnosisPairs(Pairs):
    """N paired contacts, all as float tensors.

    depth: (N, 1, S, S) gel penetration in mm (>= 0), at the image size S.
    sim, real: (N, 3, S, S) in 0..255.
    background: (3, S, S) the real sensor's no-contact frame, 0..255.
    sim_background: (3, S, S) the simulator's no-contact frame, or None when not given.
    labels: N label strings ("" when unlabelled); names: N file stems (for reports).
    gel_mm: (width, height) of the gel view the images cover, mm: slopes depend on it.

    Shape checks, ``subset`` and ``foreground`` are ``data.paired.Pairs``'s.
    """

    FRAMES: ClassVar[tuple[str, ...]] = ("background", "sim_background")
    BACKGROUNDS: ClassVar[dict[str, str]] = {"sim": "sim_background", "real": "background"}
    OPTIONAL: ClassVar[frozenset[str]] = frozenset({"sim_background"})

    depth: torch.Tensor
    sim: torch.Tensor
    real: torch.Tensor
    background: torch.Tensor
    sim_background: torch.Tensor | None
    labels: list[str]
    names: list[str]
    gel_mm: tuple[float, float] = DIGIT_GEL_MM

    def __post_init__(self) -> None:
        self._check_pairs(labels=self.labels, names=self.names)

    @property
    def size(self) -> int:
        return int(self.sim.shape[-1])

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        at = self._positions(index)
        return {"labels": [self.labels[i] for i in at], "names": [self.names[i] for i in at]}


# ----------------------------------------------------------------------------- labels
def label_to_dir(label: str) -> str:
    """The folder name a label is written under (reversed by ``dir_to_label``)."""
    if label in NAMED_LABEL_DIRS:
        return NAMED_LABEL_DIRS[label]
    name = quote(label, safe=" -_.+,=@")
    if name.startswith("."):  # ".", "..", hidden folders
        name = "%2E" + name[1:]
    return name


def dir_to_label(name: str) -> str:
    """The label a folder name stands for."""
    return _DIR_LABELS.get(name, unquote(name))


# ----------------------------------------------------------------------------- reading
def _open(path: Path) -> Image.Image:
    """An image fully decoded (so a truncated file fails here, naming it), after its header
    says it is small enough to be a frame (guard.images: no decompression bombs)."""
    im = open_header(path)
    try:
        im.load()
        return im
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, EOFError, zlib.error) as e:
        raise TactileBenchError(f"{path}: not a readable image ({e})") from None


def _check_size(path: Path, im: Image.Image, size: tuple[int, int] | None) -> tuple[int, int]:
    w, h = im.size
    if min(w, h) < MIN_SIDE:
        raise TactileBenchError(
            f"{path}: is {w} x {h}; a sensor frame here is at least {MIN_SIDE} x {MIN_SIDE}"
        )
    if size is not None and (w, h) != size:
        raise TactileBenchError(f"{path}: is {w} x {h}, the other images are {size[0]} x {size[1]}")
    return w, h


def read_rgb(
    path: Path, size: tuple[int, int] | None = None, side: int | None = None
) -> torch.Tensor:
    """(3, H, W) float 0..255 of an 8-bit RGB PNG ((3, side, side) if given); other channel
    counts are errors."""
    im = _open(path)
    if im.mode == "P":
        im = im.convert("RGB")
    if im.mode != "RGB":
        bands = len(im.getbands())
        raise TactileBenchError(
            f"{path}: has {bands} channel(s) (mode {im.mode}); expected 8-bit RGB (3 channels)"
        )
    _check_size(path, im, size)
    im = area_resized(im, side)  # 8-bit RGB in, 8-bit out: rounded as a stored frame is
    return torch.from_numpy(np.asarray(im, dtype=np.uint8).copy()).permute(2, 0, 1).float()


def read_depth(
    path: Path, size: tuple[int, int] | None = None, side: int | None = None
) -> torch.Tensor:
    """(1, H, W) float mm of a 16-bit grey PNG in micrometres ((1, side, side) if given)."""
    im = _open(path)
    if im.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise TactileBenchError(
            f"{path}: mode {im.mode} ({len(im.getbands())} channel(s)); depth must be one "
            "16-bit grey channel in micrometres"
        )
    _check_size(path, im, size)
    arr = np.asarray(im).astype(np.float32)
    if arr.min() < 0 or arr.max() > 65535:
        raise TactileBenchError(f"{path}: values outside 0..65535 micrometres")
    if arr.max() > MAX_PENETRATION_MM * UM_PER_MM:
        raise TactileBenchError(
            f"{path}: a penetration of {arr.max() / UM_PER_MM:.3g} mm; a tactile sensor's gel "
            f"is a few mm thick (at most {MAX_PENETRATION_MM:g} mm here): wrong unit?"
        )
    if side is not None:  # in 32-bit float, not rounded to whole micrometres
        arr = np.asarray(area_resized(Image.fromarray(arr, mode="F"), side), dtype=np.float32)
    return torch.from_numpy(arr / UM_PER_MM)[None]


def _listing(folder: Path) -> dict[str, tuple[str, Path]]:
    """{relative key: (label, path)} of the PNGs in ``folder`` (one optional label level)."""
    if folder.exists() and not folder.is_dir():
        raise TactileBenchError(f"{folder}: is a file, not a folder")
    if not folder.is_dir():
        raise TactileBenchError(
            f"{folder}: folder not found; a paired folder holds depth/, real/ and sim/ "
            "(PNG frames of each pair) beside background.png (docs/diagnosis.md)"
        )
    out: dict[str, tuple[str, Path]] = {}
    seen: dict[tuple[str, str], Path] = {}  # (label, name ignoring case) -> first file

    def add(path: Path, label: str) -> None:
        if path.name.startswith("."):
            return
        if path.is_dir():
            raise TactileBenchError(f"{path}: unexpected folder (one label level only)")
        if path.suffix.lower() != ".png":
            raise TactileBenchError(f"{path}: not a .png file (the paired layout holds PNGs)")
        # two files that are one pair to a reader (X.PNG beside X.png; "#" as number_sign
        # and %23) would be read twice: write_paired refuses them, so does the reader
        ident = (
            unicodedata.normalize("NFC", label),
            unicodedata.normalize("NFC", path.stem).casefold(),
        )
        if ident in seen:
            other = seen[ident]
            how = "upper/lower case" if other.stem != path.stem else "label folder"
            if other.stem.casefold() != path.stem.casefold():
                how = "Unicode form (NFC/NFD)"
            raise TactileBenchError(
                f"{path}: the same pair as {other} (label {label!r}, name {path.stem!r}; they "
                f"differ only in {how}); remove one"
            )
        seen[ident] = path
        out[str(path.relative_to(folder))] = (label, path)

    for entry in sorted(folder.iterdir()):
        if entry.is_dir() and not entry.name.startswith("."):
            for f in sorted(entry.iterdir()):
                add(f, dir_to_label(entry.name))
        else:
            add(entry, "")
    return out


def detect_layout(root: str | os.PathLike) -> tuple[str, Path]:
    """("paired" | "tactile_diffusion", the folder that holds it) for ``root``."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise TactileBenchError(f"{root}: is a file; the paired data is a folder")
    if not root.is_dir():
        raise TactileBenchError(f"{root}: folder not found")
    if (root / "depth").is_dir():
        return "paired", root
    try:  # the braille folder or its parent: the one rule of check and every stage
        return "tactile_diffusion", braille_root(root)
    except TactileBenchError:
        pass
    if (root / "sim").is_dir() or (root / "real").is_dir():
        return "paired", root  # the listing then names the missing depth/ folder
    raise TactileBenchError(
        f"{root}: not a paired layout (depth/, sim/, real/, background.png) nor the "
        "Tactile-Diffusion braille layout (real_fine_tuning/{color,mask}/, bgs/)"
    )


def working_side(frames: Sequence[tuple[int, int]], size: int | None) -> int | None:
    """The side S the diagnosis resizes frames of sizes ``frames`` (w, h) to: ``size`` if
    given, else ``min(64, shortest side)`` (64: the paper's size, the one the diagnosis is
    validated at); None when the frames are already all one square size no larger."""
    if size is not None:
        return size
    side = min(DEFAULT_SIDE, *(min(f) for f in frames))
    return None if set(frames) == {(side, side)} else side


def _check_aspect(path: Path, frame: tuple[int, int], gel: tuple[float, float]) -> None:
    """A non-square frame shows the gel view in its own proportions (square camera pixels);
    one that does not is a gel.json for another sensor, or a frame turned a quarter."""
    w, h = frame
    if w == h:
        return  # the layout's convention: a square image covers the whole view
    if abs(math.log((w / h) / (gel[0] / gel[1]))) > MAX_ASPECT_LOG_RATIO:
        raise TactileBenchError(
            f"{path}: is {w} x {h} (width x height) but the gel view is {gel[0]:g} x "
            f"{gel[1]:g} mm ({GEL_FILE} or a DIGIT's default); their proportions differ: "
            f"give {GEL_FILE} the view the frames show"
        )


def _frame_sizes(root: Path, firsts: dict[str, Path]) -> dict[str, tuple[int, int]]:
    """Each part's frame size from its first file's header (no pixel decoded)."""
    sizes = {}
    for part, path in firsts.items():
        with open_header(path) as im:
            sizes[part] = _check_size(path, im, None)
    return sizes


def _load_layout(root: Path, size: int | None = None, render_sim: bool = False) -> DiagnosisPairs:
    """The paired layout. Each part's frames share one size; the parts may differ (a
    renderer's 120 x 160 beside a camera's 240 x 320): each frame is resized on its own.
    ``render_sim`` and no sim/: the plain simulator's images over the real no-contact frame."""
    parts = PARTS if not render_sim or (root / "sim").exists() else ("depth", "real")
    listings = {part: _listing(root / part) for part in parts}
    depth_files = listings["depth"]
    if not depth_files:
        raise TactileBenchError(f"{root / 'depth'}: no PNG images")
    for part in parts[1:]:
        for key in depth_files:
            if key not in listings[part]:
                raise TactileBenchError(
                    f"{root / part / key}: missing (unpaired {root / 'depth' / key})"
                )
        for key in listings[part]:
            if key not in depth_files:
                raise TactileBenchError(
                    f"{root / part / key}: unpaired (no {root / 'depth' / key})"
                )
    first_key = next(iter(depth_files))
    frames = _frame_sizes(root, {p: root / p / first_key for p in parts})
    gel = read_gel(root)
    for part in parts:
        _check_aspect(root / part / first_key, frames[part], gel)
    side = working_side(list(frames.values()), size)
    kept = frames["real"] if side is None else (side, side)  # resized as each is read
    check_memory(  # from the headers, before decoding any pixel
        str(root),
        f"{len(depth_files)} pairs of {kept[0]} x {kept[1]} pixels",
        float(len(depth_files)) * kept[0] * kept[1] * BYTES_PER_PAIR_PIXEL,
    )
    if side is not None:
        shown = ", ".join(f"{p} {w} x {h}" for p, (w, h) in frames.items())
        log.info("%s: frames (%s) resized to %d x %d", root, shown, side, side)
    depth, sim, real, labels, names = [], [], [], [], []
    for key, (label, path) in depth_files.items():
        depth.append(read_depth(path, frames["depth"], side))
        if "sim" in frames:
            sim.append(read_rgb(root / "sim" / key, frames["sim"], side))
        real.append(read_rgb(root / "real" / key, frames["real"], side))
        labels.append(label)
        names.append(path.stem)
    # a no-contact frame is a frame of its side's camera: the same size as that side's
    background = read_rgb(root / "background.png", frames["real"], side)
    sim_bg_path = root / "sim_background.png"
    sim_bg = None
    if "sim" not in frames:  # composited onto the real frame, as TACTO's images are
        gel_spec = GelSpec(gel[0], gel[1], background.shape[-1], 1)
        sim = list(sim_render(torch.stack(depth), background, gel_spec).round().clamp(0, 255))
    elif sim_bg_path.exists():
        sim_bg = read_rgb(sim_bg_path, frames["sim"], side)
    return DiagnosisPairs(
        torch.stack(depth),
        torch.stack(sim),
        torch.stack(real),
        background,
        sim_bg,
        labels,
        names,
        gel,
    )


def read_gel(root: Path) -> tuple[float, float]:
    """The gel view of a paired folder: its ``gel.json``, else a DIGIT's 18 x 24 mm."""
    path = root / GEL_FILE
    if not path.exists():
        return DIGIT_GEL_MM
    try:
        obj = json.loads(path.read_text())
        gel = (float(obj["width_mm"]), float(obj["height_mm"]))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TactileBenchError(f"{path}: not readable JSON ({exc})".splitlines()[0]) from None
    except (KeyError, TypeError, ValueError):
        raise TactileBenchError(f"{path}: needs numbers width_mm and height_mm") from None
    if not all(np.isfinite(v) and 0 < v <= MAX_GEL_MM for v in gel):
        raise TactileBenchError(f"{path}: width_mm, height_mm must be in (0, {MAX_GEL_MM:g}] mm")
    return gel


def _load_tactile_diffusion(base: Path, size: int) -> DiagnosisPairs:
    """The release's fine-tuning pairs; sim rendered noise-free over the simulator's background."""
    from tactile_bench.data.tactile_diffusion import load_braille_pairs
    from tactile_bench.geometry.braille import CHARACTERS
    from tactile_bench.sensor.background import sim_background
    from tactile_bench.sensor.depth import GelSpec
    from tactile_bench.sensor.optics import SimOptics

    gel = GelSpec(size=size)
    pairs = load_braille_pairs(base, split="all", gel=gel)
    color = base / "real_fine_tuning" / "color"
    names = [
        f.stem
        for d in sorted(p for p in color.iterdir() if p.is_dir())
        for f in sorted(x for x in d.iterdir() if x.is_file())
    ]
    if len(names) != len(pairs.depth):  # the loader's own listing changed: fall back to indices
        names = [f"{i:05d}" for i in range(len(pairs.depth))]
    sim_bg = sim_background(size)
    sim = SimOptics().render(pairs.depth, sim_bg, None, gel).round().clamp(0, 255)
    return DiagnosisPairs(
        depth=pairs.depth.float(),
        sim=sim,
        real=pairs.real.float(),
        background=_first_background(pairs, base).float(),
        sim_background=sim_bg,
        labels=[CHARACTERS[int(i)] for i in pairs.meta["label"]],
        names=names,
    )


def _first_background(pairs: CorpusPairs, base: Path) -> torch.Tensor:
    """The first pair's no-contact frame, which ``DiagnosisPairs`` (one frame for all) keeps.

    Warns when the pairs were taken on more than one distinct frame: the others' foregrounds
    are then measured against a frame they were not recorded on.
    """
    used = pairs.real_background[torch.unique(pairs.real_bg_index)]
    distinct = len(torch.unique(used.flatten(1), dim=0))
    if distinct > 1:
        log.warning(
            "%s: the pairs carry %d distinct no-contact frames; the first pair's is used "
            "for all of them",
            base,
            distinct,
        )
    return pairs.real_background[pairs.real_bg_index[0]]


def load_paired(
    root: str | os.PathLike, size: int | None = None, render_missing_sim: bool = False
) -> DiagnosisPairs:
    """Read ``root`` in the paired layout or the Tactile-Diffusion braille layout, as
    ``size`` x ``size`` images (``working_side`` for the paired layout when None; the
    Tactile-Diffusion frames are area-resized to 64 then, like the paper's).
    ``render_missing_sim``: a paired folder without sim/ gets the plain simulator's images
    (noise-free) over its real no-contact frame; else sim/ is required."""
    if size is not None and not MIN_SIZE <= size <= MAX_SIZE:  # the CLI's bounds
        raise TactileBenchError(f"--size: must be between {MIN_SIZE} and {MAX_SIZE}, got {size}")
    layout, base = detect_layout(root)
    if layout == "tactile_diffusion":
        return _load_tactile_diffusion(base, size or DEFAULT_SIDE)
    return _load_layout(base, size, render_missing_sim)


# ----------------------------------------------------------------------------- writing
def _save_png(array: np.ndarray, path: Path) -> None:
    Image.fromarray(array).save(path, format="PNG")


def _rgb_u8(image: torch.Tensor) -> np.ndarray:
    return to_uint8(image).permute(1, 2, 0).numpy()


def write_paired(root: str | os.PathLike, data: DiagnosisPairs, overwrite: bool = False) -> Path:
    """Write ``data`` in the paired layout, atomically (a temporary folder renamed into place).

    Depth is rounded to whole micrometres (uint16, so at most 65.535 mm); images to uint8.
    An existing non-empty ``root`` is an error unless ``overwrite``.
    """
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise TactileBenchError(f"{root}: exists and is not a folder")
    if root.is_dir() and any(root.iterdir()) and not overwrite:
        raise TactileBenchError(f"{root}: exists and is not empty (overwrite it explicitly)")
    if len(data) == 0:
        raise TactileBenchError(f"{root}: no pairs to write")
    if float(data.depth.max()) * UM_PER_MM > 65535:
        raise TactileBenchError(f"{root}: depth above 65.535 mm does not fit 16-bit micrometres")
    keys = set()
    for label, name in zip(data.labels, data.names, strict=True):
        if not name or "/" in name or "\\" in name or name.startswith("."):
            raise TactileBenchError(f"{root}: pair name {name!r} is not a safe file name")
        if (label, name) in keys:
            raise TactileBenchError(f"{root}: pair {label!r}/{name!r} appears twice")
        keys.add((label, name))
    with atomic_folder(root) as tmp:
        depth_um = (data.depth[:, 0] * UM_PER_MM).round().clamp(0, 65535).numpy()
        depth_um = depth_um.astype(np.uint16)
        for i, (label, name) in enumerate(zip(data.labels, data.names, strict=True)):
            sub = label_to_dir(label) if label else ""
            for part in PARTS:
                (tmp / part / sub).mkdir(parents=True, exist_ok=True)
            _save_png(depth_um[i], tmp / "depth" / sub / f"{name}.png")
            _save_png(_rgb_u8(data.sim[i]), tmp / "sim" / sub / f"{name}.png")
            _save_png(_rgb_u8(data.real[i]), tmp / "real" / sub / f"{name}.png")
        _save_png(_rgb_u8(data.background), tmp / "background.png")
        if data.sim_background is not None:
            _save_png(_rgb_u8(data.sim_background), tmp / "sim_background.png")
        if tuple(data.gel_mm) != DIGIT_GEL_MM:
            gel = {"width_mm": float(data.gel_mm[0]), "height_mm": float(data.gel_mm[1])}
            (tmp / GEL_FILE).write_text(json.dumps(gel) + "\n")
    return root


# ----------------------------------------------------------------------------- helpers
def data_hash(data: DiagnosisPairs) -> str:
    """Content hash of the pairs (as 8-bit images and whole micrometres), for reports."""
    digest = hashlib.sha256()
    digest.update((data.depth * UM_PER_MM).round().to(torch.int32).numpy().tobytes())
    for t in (data.sim, data.real, data.background, data.sim_background):
        if t is not None:
            digest.update(to_uint8(t).numpy().tobytes())
    digest.update(
        "\n".join(f"{a}/{b}" for a, b in zip(data.labels, data.names, strict=True)).encode()
    )
    return digest.hexdigest()


def from_braille_set(bset: object, chars: Sequence[str]) -> DiagnosisPairs:
    """A ``data.braille.BrailleSet`` as paired data; labels are the characters ``chars``."""
    from tactile_bench.data.braille import BrailleSet

    if not isinstance(bset, BrailleSet):
        raise TactileBenchError("from_braille_set: expected a BrailleSet")
    labels = bset.labels.tolist()
    if labels and max(labels) >= len(chars):
        raise TactileBenchError(
            f"braille set: label {max(labels)} outside the {len(chars)} characters {''.join(chars)}"
        )
    return DiagnosisPairs(
        depth=bset.depth.float().clamp(min=0),
        sim=bset.sim.float(),
        real=bset.real.float(),
        background=bset.real_background.float(),
        sim_background=bset.sim_background.float(),
        labels=[chars[i] for i in labels],
        names=[f"{i:05d}" for i in range(len(labels))],
    )


def braille_stage_chars(stage_dir: str | os.PathLike) -> tuple[str, ...] | None:
    """The characters a ``braille_data`` stage was built with (its ``_done.json`` config);
    None when the folder holds no such manifest (a bare .npz)."""
    try:
        chars = json.loads((Path(stage_dir) / "_done.json").read_text())["config"]["chars"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return tuple(chars) if isinstance(chars, str) else None
