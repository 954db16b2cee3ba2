"""Output locations checked before the work, and locked while a run writes them.

A diagnosis, fit or render that runs for minutes and then finds its ``--out`` is a file, lies
under a file, or sits in a read-only folder wastes the work: :func:`check_output_dir` and
:func:`check_output_file` find that first by writing (and removing) a probe file where the
output will go. :class:`OutputLock` keeps two runs off one run dir or output folder: the
second is refused in one line naming the process that holds it. The lock is an ``flock`` on
a hidden file beside the output, so the kernel drops it when its process dies: a lock left
by a killed run is taken over (and said so) instead of blocking forever.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

from tactile_bench.errors import TactileBenchError

log = logging.getLogger("tactile_bench")


def _nearest_existing(path: Path, key: str) -> Path:
    """``path`` or its closest ancestor that exists; an ancestor that is a file is an error."""
    try:
        return _walk_up(path)
    except OSError as exc:  # a name too long, a loop of links, an unreadable parent
        raise TactileBenchError(f"{key} {path}: {exc.strerror or exc}") from None


def _walk_up(path: Path) -> Path:
    here = path
    while True:
        if here.exists():
            return here
        if here.is_symlink():  # dangling link: where it points is missing
            raise TactileBenchError(f"{path}: {here} is a dangling symbolic link")
        if here == here.parent:
            return here
        here = here.parent


def _probe(folder: Path, key: str, path: Path) -> None:
    """Write and remove a file in ``folder``: permissions, read-only disks, immutable folders."""
    try:
        fd, name = tempfile.mkstemp(prefix=".tactile_bench_probe.", dir=folder)
    except OSError as exc:
        raise TactileBenchError(
            f"{key} {path}: cannot write in {folder} ({exc.strerror or exc})"
        ) from None
    os.close(fd)
    os.unlink(name)


def check_output_dir(path: str | os.PathLike[str], key: str) -> Path:
    """A folder that can be created and written, checked before any work; returns it."""
    path = Path(path)
    if str(path) == "":
        raise TactileBenchError(f"{key}: an empty path")
    base = _nearest_existing(path, key)
    if not base.is_dir():
        if base == path:
            raise TactileBenchError(f"{key} {path}: exists and is not a folder")
        raise TactileBenchError(f"{key} {path}: lies under {base}, which is a file")
    _probe(base, key, path)
    return path


def check_output_file(path: str | os.PathLike[str], key: str, suffixes: Sequence[str] = ()) -> Path:
    """A file that can be written, with one of ``suffixes`` (it is written in that format)."""
    path = Path(path)
    if suffixes and path.suffix.lower() not in suffixes:
        raise TactileBenchError(
            f"{key} {path}: writes {'/'.join(s.lstrip('.').upper() for s in suffixes)}; "
            f"give a file name ending in {' or '.join(suffixes)}"
        )
    if path.is_dir():
        raise TactileBenchError(f"{key} {path}: is a folder; give a file name")
    if path.exists() and not path.is_file():
        raise TactileBenchError(f"{key} {path}: exists and is not a regular file")
    base = _nearest_existing(path.parent if str(path.parent) else Path("."), key)
    if not base.is_dir():
        raise TactileBenchError(f"{key} {path}: lies under {base}, which is a file")
    _probe(base, key, path)
    return path


def lock_path(target: Path) -> Path:
    """The lock file of an output: hidden, beside it (so the output folder stays as written);
    inside it when it is the working folder, one above it, or ``/`` (``bench --out .``):
    nothing is written above where the user works."""
    target = Path(os.path.abspath(target))
    cwd = Path(os.path.abspath(os.curdir))
    if target == target.parent or target == cwd or target in cwd.parents:
        return target / ".tactile_bench.lock"
    return target.parent / f".{target.name}.tactile_bench.lock"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class OutputLock:
    """An exclusive lock on one output (run dir, ``--out`` folder or file) for one process.

    ``with OutputLock(path, "--out"):`` refuses a second holder at once with the holder's pid
    and command; re-entering in the same process (a command calling another) is allowed.
    """

    _held: dict[str, int] = {}  # lock file -> depth, in this process

    def __init__(self, target: str | os.PathLike[str], key: str) -> None:
        self.target = Path(target)
        self.key = key
        self.path = lock_path(self.target)
        self._fd: int | None = None

    def _describe_holder(self) -> str:
        try:
            info = json.loads(self.path.read_text() or "{}")
        except (OSError, ValueError):
            info = {}
        pid = info.get("pid", "?")
        since = info.get("since")
        when = time.strftime(" since %H:%M:%S", time.localtime(since)) if since else ""
        command = info.get("command", "")
        host = info.get("host", "")
        return f"process {pid}{f' on {host}' if host else ''}{when} ({command})"

    def acquire(self) -> OutputLock:
        key = str(self.path)
        if key in self._held:
            self._held[key] += 1
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(20):  # the holder may unlink the file between our open and flock
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise TactileBenchError(
                    f"{self.key} {self.target}: in use by {self._describe_holder()}; wait for "
                    "it to finish or stop it, or choose another"
                ) from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        else:  # pragma: no cover - a file replaced 20 times in a row
            raise TactileBenchError(f"{self.key} {self.target}: cannot take its lock {key}")
        try:
            old = json.loads(os.pread(fd, 4096, 0) or b"{}")
        except ValueError:
            old = {}
        if isinstance(old, dict) and old.get("pid") and old.get("pid") != os.getpid():
            state = "no longer running" if not _alive(int(old["pid"])) else "its lock released"
            log.warning(
                "%s %s: taking over the lock left by process %s (%s)",
                self.key,
                self.target,
                old["pid"],
                state,
            )
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since": time.time(),
            "command": " ".join(["tactile_bench", *sys.argv[1:]])[:300],
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        self._fd = fd
        self._held[key] = 1
        return self

    def release(self) -> None:
        key = str(self.path)
        depth = self._held.get(key, 0)
        if depth > 1:
            self._held[key] = depth - 1
            return
        self._held.pop(key, None)
        if self._fd is not None:
            try:
                self.path.unlink(missing_ok=True)
            finally:
                os.close(self._fd)  # closing drops the flock
                self._fd = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()
