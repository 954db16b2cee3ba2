"""Atomic writes and content hashes: nothing half-written, corrupt caches detected."""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.files import require_not_special
from tactile_bench.guard.limits import disk_full_error


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _atomic(path: Path, write: Callable[[Path], None]) -> Path:
    """Write through a temporary file in the same directory, then rename over ``path``.

    A full disk is a one-line error naming ``path`` and the space left, measured after the
    partial temporary file is removed."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
        tmp = Path(tmp_name)
        try:
            write(tmp)
            # mkstemp makes the file private (0600); results are files like any other
            tmp.chmod(0o666 & ~_UMASK)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    except OSError as exc:
        if exc.filename is None:  # a write to the open temporary file: it was ``path``
            exc.filename = str(path)
        full = disk_full_error(exc, path)
        if full is None:
            raise
        raise full from None
    return path


@contextmanager
def atomic_folder(out: Path) -> Iterator[Path]:
    """A temporary folder next to ``out``, renamed to ``out`` when the block succeeds (an
    existing ``out`` replaced); removed, with ``out`` untouched, when it fails: a folder of
    outputs is never seen half-written."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        yield tmp
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.replace(out, old / out.name)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def atomic_write_text(path: Path, text: str) -> Path:
    """Write a text file atomically."""
    return _atomic(path, lambda tmp: tmp.write_text(text))


def atomic_write_json(path: Path, obj: Any) -> Path:
    """Write JSON atomically, pretty-printed so results diff well in git."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def atomic_torch_save(obj: Any, path: Path) -> Path:
    """torch.save atomically, and byte-for-byte reproducibly.

    torch names the zip archive inside after the file it writes to; saving straight to the
    random temporary name would make equal weights hash differently on every run (and every
    downstream stage's cache key with them). Serialising in memory names it ``archive``.
    """
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return _atomic(path, lambda tmp: tmp.write_bytes(buffer.getvalue()))


def file_sha256(path: Path, chunk: int = 1 << 20) -> str:
    """Content hash of a file, recorded in manifests and checked before a cached file is reused."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def json_sha256(obj: Any) -> str:
    """Stable hash of a JSON-able value (sorted keys), used to key cached stages."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def atomic_write_npz(path: Path, **arrays: Any) -> Path:
    """np.savez atomically (uncompressed: these caches are read far more often than written)."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            np.savez(handle, **arrays)

    return _atomic(path, write)


def load_npz(path: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    """Read the named arrays of an .npz, turning a missing/corrupt file into a one-line error."""
    require_not_special(path, "data file")  # a FIFO would block np.load
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in keys if k not in data.files]
            if missing:
                raise TactileBenchError(f"{path}: missing arrays {missing}")
            return {k: data[k] for k in keys}
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: file not found") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise TactileBenchError(f"{path}: corrupt or truncated ({exc})") from None
