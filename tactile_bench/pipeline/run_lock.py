"""The run-dir lock of a launch that may span machines.

:class:`~tactile_bench.guard.outputs.OutputLock` is an ``flock``: the kernel drops it when its
process dies, but a cluster's run dirs live on NFS, where one machine's ``flock`` need not
stop another's. So the lock also claims an *owner file* beside the run dir, made by a hard
link (atomic on NFS, as ``O_EXCL`` was not before NFSv3) and naming the host, pid and launch
id of its holder. The holder touches it every :data:`HEARTBEAT_S` seconds; a claim whose
file has not been touched for :data:`STALE_S` seconds is a dead launch's, and is taken over
with a warning (a claim of this host whose process is gone is taken over at once). Only
global rank 0 takes the lock; the other ranks of its launch check that they see the claim
with their launch id, which also proves the run dir is on storage they share.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import sys
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.outputs import OutputLock, lock_path

log = logging.getLogger("tactile_bench")

#: how often the holder touches its owner file
HEARTBEAT_S = 30.0
#: a claim untouched this long belongs to a launch that died (NFS caches attributes ~60 s)
STALE_S = 300.0


def owner_path(run_dir: Path) -> Path:
    """The owner file of a run dir: hidden, beside its flock file."""
    flock = lock_path(run_dir)
    return flock.with_name(flock.name.removesuffix(".lock") + ".owner")


def read_owner(path: Path) -> dict[str, Any] | None:
    """The claim in an owner file, or None when there is none (or it is unreadable)."""
    try:
        info = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


class RunDirLock:
    """``with RunDirLock(run_dir, launch_id):`` the run dir is this launch's until the end."""

    def __init__(self, run_dir: Path, launch_id: str, key: str = "run dir") -> None:
        self.run_dir = Path(run_dir)
        self.launch_id = launch_id
        self.key = key
        self.path = owner_path(self.run_dir)
        self._flock = OutputLock(self.run_dir, key)
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    def _claim(self) -> dict[str, Any]:
        return {
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "launch": self.launch_id,
            "since": time.time(),
            "command": " ".join(["tactile_bench", *sys.argv[1:]])[:300],
        }

    def _try_link(self, claim: dict[str, Any]) -> bool:
        tmp = self.path.with_name(f"{self.path.name}.{socket.gethostname()}.{os.getpid()}")
        tmp.write_text(json.dumps(claim))
        try:
            os.link(tmp, self.path)
            return True
        except FileExistsError:
            return False
        finally:
            tmp.unlink(missing_ok=True)

    def _refuse(self, holder: dict[str, Any], age: float) -> TactileBenchError:
        since = holder.get("since")
        when = time.strftime(" since %H:%M:%S", time.localtime(since)) if since else ""
        return TactileBenchError(
            f"{self.key} {self.run_dir}: in use by process {holder.get('pid', '?')} on "
            f"{holder.get('host', '?')} (launch {holder.get('launch', '?')}{when}, last seen "
            f"{age:.0f} s ago: {holder.get('command', '')}); wait for it to finish or stop "
            f"it, or choose another (a claim unseen for {STALE_S:.0f} s is taken over)"
        )

    def acquire(self) -> RunDirLock:
        self._flock.acquire()  # this host: refused at once while the holder lives
        try:
            self._claim_owner_file()
        except BaseException:
            self._flock.release()
            raise
        self._beat = threading.Thread(target=self._heartbeat, name="run-dir-lock", daemon=True)
        self._beat.start()
        return self

    def _claim_owner_file(self) -> None:
        claim = self._claim()
        for _ in range(5):  # another host may take over between our read and our link
            if self._try_link(claim):
                return
            holder = read_owner(self.path) or {}
            try:
                age = time.time() - self.path.stat().st_mtime
            except FileNotFoundError:
                continue
            # this host's flock is ours, so a claim of this host is a dead process's
            same_host = holder.get("host") == socket.gethostname()
            if not (same_host or age > STALE_S):
                raise self._refuse(holder, age)
            log.warning(
                "%s %s: taking over the claim of process %s on %s (launch %s): %s",
                self.key,
                self.run_dir,
                holder.get("pid", "?"),
                holder.get("host", "?"),
                holder.get("launch", "?"),
                "no longer running" if same_host else f"unseen for {age:.0f} s",
            )
            self.path.unlink(missing_ok=True)
        raise TactileBenchError(f"{self.key} {self.run_dir}: cannot claim {self.path}")

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT_S):
            try:
                os.utime(self.path)
            except OSError:  # the file went (a user removed it): keep running, say so
                log.warning("%s %s: its lock file %s is gone", self.key, self.run_dir, self.path)
                return

    def release(self) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
        holder = read_owner(self.path)
        if holder is not None and holder.get("launch") == self.launch_id:
            self.path.unlink(missing_ok=True)
        self._flock.release()

    def __enter__(self) -> RunDirLock:
        return self.acquire()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()


def check_claim(run_dir: Path, launch_id: str) -> str | None:
    """On a follower: None when the run dir's owner file names this launch, else why not."""
    holder = read_owner(owner_path(Path(run_dir)))
    if holder is None:
        return f"{socket.gethostname()} does not see {owner_path(Path(run_dir))}"
    if holder.get("launch") != launch_id:
        return f"{socket.gethostname()} sees the claim of launch {holder.get('launch')}"
    return None
