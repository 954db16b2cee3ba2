"""Images checked from their header (size, mode, pixel count) before any pixel is decoded,
then decoded whole, so that a truncated file fails when it is read, not inside a fit.

A 30000 x 30000 PNG of a few megabytes decodes to gigabytes; Pillow only refuses beyond
~179 megapixels, and with its own exception. A tactile frame is small (a DIGIT's is
320 x 240), so anything above :data:`MAX_PIXELS` is refused from the header alone.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

from PIL import Image

from tactile_bench.errors import TactileBenchError

#: the largest image a reader decodes: 4096 x 4096 (a DIGIT frame is 320 x 240)
MAX_PIXELS = 4096 * 4096
#: the smallest side of a sensor frame the models can use (recipes' image_size >= 16)
MIN_SIDE = 16
#: colour modes that hold a 3-channel RGB frame (a palette PNG expands to RGB)
RGB_MODES = ("RGB", "P")


def open_header(path: str | os.PathLike[str], max_pixels: int = MAX_PIXELS) -> Image.Image:
    """The image opened lazily (header only), refused when it is too large to be a frame.

    The caller decodes with ``im.load()`` after any further header checks; the file stays
    open until then (use it as a context manager or close it).
    """
    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(path)
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise TactileBenchError(f"{path}: is a folder, not an image") from None
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise TactileBenchError(
            f"{path}: image too large to be a sensor frame (more than {max_pixels} pixels)"
        ) from None
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError ... on bad bytes
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise TactileBenchError(
            f"{path}: not a readable image (corrupt or truncated? {reason})"
        ) from None
    w, h = im.size
    if w * h > max_pixels:
        im.close()
        raise TactileBenchError(
            f"{path}: {w} x {h} pixels ({w * h} in all); a sensor frame here is at most "
            f"{max_pixels} pixels: refused before decoding"
        )
    return im


def open_image(path: str | os.PathLike[str]) -> Image.Image:
    """The fully decoded image, or a one-line error saying what is wrong with the file."""
    path = Path(path)
    try:
        with open_header(path) as im:  # size and pixel count from the header, then decode
            im.load()  # decode now: a truncated file fails here
            return im.copy()
    except TactileBenchError:
        raise
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise TactileBenchError(f"{path}: is a folder, not an image") from None
    except Image.DecompressionBombError as exc:
        raise TactileBenchError(f"{path}: image too large to be a sensor frame ({exc})") from None
    except Exception as exc:  # PIL raises OSError, SyntaxError, ValueError ... on bad bytes
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise TactileBenchError(
            f"{path}: not a readable image (corrupt or truncated? {reason})"
        ) from None
