"""One recipe over several processes: Lightning's ``ddp`` launcher, ``torchrun`` or SLURM.

The processes are started and joined by Lightning's own machinery, at start-up, before any
stage: ``lightning.Fabric(...).launch()`` re-runs the command for the other local ranks when
the recipe asks for ``strategy: ddp`` on several devices (Lightning's subprocess launcher,
which sets ``LOCAL_RANK``, ``NODE_RANK``, ``WORLD_SIZE``, ``MASTER_ADDR``/``PORT`` for them),
and under ``torchrun`` or ``srun`` it only reads the rank the launcher set
(``TorchElasticEnvironment``, ``SLURMEnvironment``) and joins the process group. Every
``lightning.Trainer`` of the run then finds the processes started and the group joined, and
trains on all of them.

Global rank 0, the *leader*, owns the run dir: its lock, the cache decisions, the manifests
and reports (NeMo's ``exp_manager`` and Lightning's ``rank_zero_only`` split the work the same
way). It hands each stage to the others, the *followers*, over a gloo group of its own:
a stage that trains (``StageKind.fits``) runs on every rank, a follower writing only into a
scratch folder of its own (Lightning already saves checkpoints on rank 0 only); any other
stage runs on the leader while the followers wait for its next message. The wait has no
time limit that a long data stage could reach, and a leader that dies ends it at once (its
sockets close).
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import tempfile
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

from tactile_bench.errors import TactileBenchError
from tactile_bench.training import device_count

log = logging.getLogger("tactile_bench")

#: the trainer settings that say how many processes train (not what one of them computes)
LAUNCH_KEYS = ("strategy", "devices", "num_nodes")
#: how long a follower waits for the leader's next message (a data stage can take a day)
FOLLOWER_WAIT = timedelta(days=7)


@dataclass(frozen=True)
class Launch:
    """This process's place in a launch of ``world_size`` processes."""

    world_size: int
    rank: int
    launcher: str  # torchrun | slurm | lightning
    launch_id: str
    group: Any  # the gloo process group of the leader's messages

    @property
    def leader(self) -> bool:
        """Global rank 0: the process that owns the run dir."""
        return self.rank == 0

    def describe(self) -> str:
        return f"rank {self.rank} of {self.world_size} ({self.launcher}, launch {self.launch_id})"


_current: Launch | None = None


def current() -> Launch | None:
    """The launch this process belongs to, once :func:`start` has run (None: one process)."""
    return _current


def is_leader() -> bool:
    """True in a one-process run and on global rank 0 of a launch."""
    return _current is None or _current.leader


def _int_env(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


def launched_externally() -> tuple[str, int, int] | None:
    """``(launcher, world size, processes per node)`` when torchrun, srun or Lightning's
    launcher started this process as one of several; None otherwise. Read from the
    environment by Lightning's cluster environments."""
    from lightning.fabric.plugins.environments import SLURMEnvironment, TorchElasticEnvironment

    if TorchElasticEnvironment.detect():
        world = _int_env("WORLD_SIZE", 1)
        return ("torchrun", world, _int_env("LOCAL_WORLD_SIZE", world)) if world > 1 else None
    if SLURMEnvironment.detect():
        world = _int_env("SLURM_NTASKS", 1)
        nodes = max(1, _int_env("SLURM_JOB_NUM_NODES", _int_env("SLURM_NNODES", 1)))
        per_node = _int_env("SLURM_NTASKS_PER_NODE", max(1, world // nodes))
        return ("slurm", world, per_node) if world > 1 else None
    if "LOCAL_RANK" in os.environ and _int_env("WORLD_SIZE", 1) > 1:
        world = _int_env("WORLD_SIZE", 1)
        nodes = max(1, _int_env("TACTILE_BENCH_NUM_NODES", 1))
        return "lightning", world, world // nodes
    return None


def _asks_for_ddp(trainer: Mapping[str, Any]) -> bool:
    """Lightning's subprocess launcher (``strategy: ddp`` and its variants, not the spawn
    or notebook ones) on more than one process."""
    strategy = trainer.get("strategy")
    if not isinstance(strategy, str) or not strategy.startswith("ddp"):
        return False
    if any(word in strategy for word in ("spawn", "fork", "notebook")):
        return False
    per_node = device_count(trainer.get("devices", "auto")) or 1
    nodes = int(trainer.get("num_nodes", 1) or 1)
    return per_node * nodes > 1


def completed_trainer(trainer: Mapping[str, Any], world: int, per_node: int) -> dict[str, Any]:
    """The recipe's trainer settings with what the launch decided filled in (``strategy:
    ddp``, ``devices`` per node, ``num_nodes``); a setting that contradicts it is an error."""
    settings = dict(trainer)
    nodes = max(1, world // max(1, per_node))
    wanted = {"strategy": "ddp", "devices": per_node, "num_nodes": nodes}
    for key, value in wanted.items():
        given = settings.get(key)
        if given is None or given == "auto":
            settings[key] = value
            continue
        count = device_count(given) if key == "devices" else given
        if key == "strategy":
            if not (isinstance(given, str) and given.startswith("ddp")) or "spawn" in given:
                raise TactileBenchError(
                    f"trainer.strategy: {given!r} under a launch of {world} processes; use ddp "
                    "(the launcher has started the processes)"
                )
        elif count != value:
            raise TactileBenchError(
                f"trainer.{key}: {given!r}, but the launcher started {world} processes, "
                f"{per_node} per node on {nodes} node(s); set {key}: {value} or leave it out"
            )
    return settings


def start(trainer: Mapping[str, Any]) -> tuple[Launch | None, dict[str, Any]]:
    """Join (or, for ``strategy: ddp`` run as one command, start) the launch this recipe
    runs in; returns it (None for one process) and the trainer settings it trains with."""
    global _current
    if _current is not None:
        return _current, completed_trainer(trainer, _current.world_size, _per_node())
    outside = launched_externally()
    if outside is None and not _asks_for_ddp(trainer):
        return None, dict(trainer)
    import lightning as L
    import torch.distributed as dist

    if outside is None:  # Lightning's launcher: this command is rank 0, it starts the others
        fabric_settings = {k: trainer[k] for k in (*LAUNCH_KEYS, "accelerator") if k in trainer}
        launcher = "lightning"
    else:
        launcher, world, per_node = outside
        settings = completed_trainer(trainer, world, per_node)
        fabric_settings = {k: settings[k] for k in (*LAUNCH_KEYS, "accelerator") if k in settings}
    # the children read the node count back (LightningEnvironment has no variable for it)
    os.environ.setdefault("TACTILE_BENCH_NUM_NODES", str(fabric_settings.get("num_nodes", 1)))
    try:
        fabric = L.Fabric(**fabric_settings)
        fabric.launch()
    except (ValueError, RuntimeError) as exc:  # Lightning's checks of devices against the launch
        reason = str(exc).strip().splitlines()[0][:240] if str(exc).strip() else repr(exc)
        raise TactileBenchError(f"trainer: the launch refuses these settings: {reason}") from None
    world, rank = fabric.world_size, fabric.global_rank
    group = dist.new_group(backend="gloo", timeout=FOLLOWER_WAIT)
    ids = [uuid.uuid4().hex[:12] if rank == 0 else None]
    dist.broadcast_object_list(ids, src=0, group=group)
    _current = Launch(world, rank, launcher, str(ids[0]), group)
    if not _current.leader:
        # one voice: the leader logs the run, a follower only its warnings and errors
        logging.getLogger("tactile_bench").setLevel(logging.WARNING)
    log.info(
        "launch %s: %d processes (%s), this is rank %d on %s",
        _current.launch_id,
        world,
        launcher,
        rank,
        socket.gethostname(),
    )
    return _current, completed_trainer(trainer, world, _per_node())


def finish(launch: Launch) -> None:
    """End this process's part of a launch that ran to its end: wait for every rank, then
    destroy the process groups (Lightning's and the leader's) while the interpreter is whole.

    Lightning destroys them at exit for NCCL only; a gloo group left to the interpreter's
    finalisation can still hold worker threads, and the process then aborts at exit
    (``terminate called without an active exception``, SIGABRT), so torchrun reports a
    finished launch failed. Only after success: a rank whose peers are gone or inside a
    collective would wait here instead of exiting with its error. The process keeps its
    place in the launch (:func:`current`, :func:`is_leader`): a follower still prints nothing.
    """
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.barrier(group=launch.group)
        dist.destroy_process_group()


def _per_node() -> int:
    assert _current is not None
    outside = launched_externally()
    return outside[2] if outside is not None else _current.world_size


def share(launch: Launch, message: Any = None) -> Any:
    """The leader's ``message``, on every rank (the others pass None and wait for it)."""
    import torch.distributed as dist

    box = [message if launch.leader else None]
    dist.broadcast_object_list(box, src=0, group=launch.group)
    return box[0]


@contextmanager
def scratch_dir(launch: Launch, stage: str) -> Iterator[Path]:
    """A follower's private folder for a stage's files (removed after): what it writes
    there never reaches the run dir, which only the leader writes."""
    folder = Path(tempfile.mkdtemp(prefix=f"tactile_bench-{stage}-rank{launch.rank}-"))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def single_process_trainer(trainer: Mapping[str, Any]) -> dict[str, Any]:
    """Settings for a fit on the leader alone (a stage that does not train on every rank)."""
    return {**trainer, "strategy": "auto", "devices": 1, "num_nodes": 1}


def gather(launch: Launch, value: Any) -> list[Any]:
    """Every rank's ``value``, in rank order, on every rank."""
    import torch.distributed as dist

    values: list[Any] = [None] * launch.world_size
    dist.all_gather_object(values, value, group=launch.group)
    return values
