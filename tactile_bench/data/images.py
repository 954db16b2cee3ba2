"""Reading users' image files: every problem is one line naming the file, never a traceback.

Real folders are messy: a frame cut short by a full disk, a screenshot saved as RGBA, a
grey-scale export, a frame of another camera resolution, a stray ``.DS_Store``. The readers
here decode the whole file (so a truncated one fails now, not inside a training) and, with a
:class:`SameSize`, check that every frame of a dataset has one size: resizing a frame of
another size would silently mix two sensors' geometries.

The released datasets' own loaders read every image with ``cv2.imread(path)``, which gives
8-bit, 3-channel colour whatever the file holds: a grey file's level goes to all three
channels, an alpha channel is dropped, 16 bits become 8 (>> 8). The readers of those layouts
do the same (:func:`read_image`, :func:`read_mask`), so a folder the original code trains on
is read here too; a frame that was not stored as RGB is named once in a warning.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.images import RGB_MODES, open_image

#: Pillow's modes of 16- and 32-bit integer grey; ``cv2.imread`` keeps their high byte
_WIDE_GREY = ("I;16", "I;16B", "I;16L", "I")

log = logging.getLogger("tactile_bench")
#: (mode, dataset folder) already named in a warning, like the ``warnings`` module's registry
_noted: set[tuple[str, Path]] = set()


def is_hidden(path: Path) -> bool:
    """``.DS_Store``, ``._frame.png``, ``.ipynb_checkpoints``: never data."""
    return path.name.startswith(".")


class SameSize:
    """Every image of one dataset has the size of the first one read."""

    def __init__(self, what: str = "frames") -> None:
        self.what = what
        self.size: tuple[int, int] | None = None
        self.first: Path | None = None

    def check(self, path: Path, size: tuple[int, int]) -> None:
        if self.size is None:
            self.size, self.first = size, path
        elif size != self.size:
            w, h = size
            raise TactileBenchError(
                f"{path}: {w} x {h} pixels, but {self.first} is {self.size[0]} x "
                f"{self.size[1]}: all {self.what} of a dataset must share one size"
            )


def _channels(im: Image.Image) -> str:
    n = len(im.getbands())
    return f"{n} channel{'s' if n != 1 else ''} (mode {im.mode})"


def as_imread_colour(im: Image.Image, path: Path) -> Image.Image:
    """The 8-bit RGB image ``cv2.imread(path)`` (``IMREAD_COLOR``) would give for ``im``.

    Grey levels go to R, G and B alike, alpha is dropped (not composited), 16-bit grey keeps
    its high byte. Only what ``imread`` cannot read as colour either is an error.
    """
    if im.mode in _WIDE_GREY:
        grey = np.clip(np.asarray(im, dtype=np.int64) >> 8, 0, 255).astype(np.uint8)
        return Image.fromarray(grey, "L").convert("RGB")
    if im.mode in ("LA", "La", "PA"):
        im = im.convert("RGBA") if im.mode == "PA" else im.convert("L")
    try:
        return im.convert("RGB")
    except (ValueError, OSError) as exc:
        raise TactileBenchError(
            f"{path}: {_channels(im)} cannot be read as colour ({exc})"
        ) from None


def _note_mode(path: Path, im: Image.Image) -> None:
    """Say that a frame was not RGB: usually an export, sometimes a wrong folder, which the
    user should hear of although the original reads it silently. Once per mode and dataset
    folder (``<folder>/<label or frames>/<file>``), not once per frame."""
    key = (im.mode, path.parent.parent)
    if im.mode in RGB_MODES or key in _noted:
        return
    _noted.add(key)
    log.warning(
        "%s: %s; read as the original loaders read it (cv2.imread: 8-bit, 3 channels, alpha "
        "dropped); other frames of this mode are read the same way without a note",
        path,
        _channels(im),
    )


def area_resized(im: Image.Image, size: int | None) -> Image.Image:
    """``im`` as ``size`` x ``size`` by Pillow's box filter, cv2's INTER_AREA: each new pixel
    the mean of the old ones it covers, as a coarser camera pixel integrates their light
    (unchanged for ``size`` None or a frame already that size)."""
    if size is None or im.size == (size, size):
        return im
    return im.resize((size, size), Image.Resampling.BOX)


def read_image(path: Path, size: int | None = None, same: SameSize | None = None) -> torch.Tensor:
    """(3, S, S) uint8 RGB of a colour frame as ``cv2.imread`` reads it, area-resized to
    ``size`` (cv2 INTER_AREA)."""
    im = open_image(path)
    if same is not None:
        same.check(Path(path), im.size)
    _note_mode(Path(path), im)
    im = area_resized(as_imread_colour(im, Path(path)), size)
    return torch.from_numpy(np.asarray(im, dtype=np.uint8).copy()).permute(2, 0, 1)


#: cv2's COLOR_RGB2GRAY weights. dataio_braille.py applies it to what cv2.imread gives (B, G, R
#: order), so the file's blue channel gets the 0.299; on grey masks (equal channels) it is exact.
_RGB2GRAY = np.array([0.299, 0.587, 0.114])


def read_mask(path: Path, size: int | None = None, weights_bgr_as_rgb: bool = True) -> np.ndarray:
    """(S, S) float64 grey levels 0..255 of a depth mask, read as the original reads it.

    Tactile-Diffusion (``dataio_braille.py``: ``cv2.imread`` then ``cv2.COLOR_RGB2GRAY``;
    ``dataio_ycb.py``: ``COLOR_BGR2GRAY``) takes any image as 8-bit colour and converts it to
    grey, then resizes it to the model size on its own (INTER_AREA), whatever the frame's size.
    So a mask stored as colour (3 equal channels from ``cv2.imwrite``, or a tinted export) or
    at another size than its frame is read, not refused; 16-bit masks become 8-bit (>> 8) as
    ``cv2.imread`` makes them. ``weights_bgr_as_rgb``: the braille loader's channel order
    (False: ``dataio_ycb.py``'s correct BGR2GRAY).
    """
    im = open_image(path)
    if im.mode in _WIDE_GREY + ("L",):
        grey = np.asarray(as_imread_colour(im, Path(path)), dtype=np.float64)[..., 0]
    else:
        rgb = np.asarray(as_imread_colour(im, Path(path)), dtype=np.float64)
        weights = _RGB2GRAY[::-1] if weights_bgr_as_rgb else _RGB2GRAY
        grey = np.floor(rgb @ weights + 0.5)  # cv2 rounds to the nearest level
    im = Image.fromarray(np.clip(grey, 0, 255).astype(np.uint8), "L")
    if size is not None:
        im = im.resize((size, size), Image.Resampling.BOX)
    return np.asarray(im, dtype=np.float64)
