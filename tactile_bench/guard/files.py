"""Input files: regular files only. A FIFO blocks a reader forever, ``/dev/zero`` never
ends, a socket cannot be read: none of them is a recipe, a checkpoint or an image."""

from __future__ import annotations

import os
import stat

from tactile_bench.errors import TactileBenchError

_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def special_kind(path: str | os.PathLike[str]) -> str | None:
    """ "a FIFO (named pipe)", "a character device", ... for a special file, else None."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return next((name for test, name in _KINDS if test(mode)), None)


def require_not_special(path: str | os.PathLike[str], what: str) -> None:
    """Refuse ``path`` when it is a FIFO, device or socket (before anything opens it)."""
    kind = special_kind(path)
    if kind is not None:
        raise TactileBenchError(f"{path}: {kind}, not a file or folder a {what} is read from")
