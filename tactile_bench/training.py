"""Lightning fits that survive the night: periodic checkpoints, exact resume, NaN stop, Ctrl-C.

Every training in the project (translator fits, classifiers) goes through
:func:`resumable_fit`. It writes ``<dir>/last.ckpt`` every ``checkpoint_every_n_steps``
optimizer steps (Lightning's save is atomic: temporary file, then move) and at the end.
A rerun that finds that file passes it to ``trainer.fit(ckpt_path=...)`` and continues.

Why the result of a resumed fit equals an uninterrupted one: Lightning restores weights,
optimizer and loop counters; the checkpoint also carries the global RNG states (dropout,
diffusion noise, augmentation) and the data position. :class:`ResumableSampler` is the
``RandomSampler`` a ``DataLoader(shuffle=True, generator=g)`` uses, drawing from the same
generator ``g`` in the same order (so the batch order is unchanged), whose position
(the generator state at the start of the epoch, batches already done) can be restored.

A NaN or infinite loss stops the fit with a :class:`TactileBenchError` naming the step;
weights are checked before every save, so the last checkpoint is always a good one.
The first Ctrl-C (SIGINT) or a SIGTERM finishes the current step, saves, and raises
``KeyboardInterrupt``; a second Ctrl-C aborts at once (the last periodic checkpoint stays).
"""

from __future__ import annotations

import logging
import random
import signal
import threading
import warnings
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any, Protocol

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback
from torch.utils.data import RandomSampler, Sampler

from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import use_tensor_cores
from tactile_bench.io import json_sha256

log = logging.getLogger("tactile_bench")

#: recipe ``trainer:`` key (not a Trainer argument) setting the checkpoint interval
EVERY_KEY = "checkpoint_every_n_steps"
DEFAULT_EVERY = 100
#: on an accelerator, losses are checked for NaN/inf this often (steps) and before each save
DEVICE_CHECK_EVERY = 32
CHECKPOINT_NAME = "last.ckpt"
#: trainer settings that change how a fit is shown or saved, never what it computes
NEUTRAL_TRAINER_KEYS = frozenset(
    {
        EVERY_KEY,
        "enable_checkpointing",
        "enable_progress_bar",
        "enable_model_summary",
        "log_every_n_steps",
        "logger",
        "callbacks",
        "default_root_dir",
    }
)


def device_count(devices: Any) -> int | None:
    """How many processes per node ``devices`` asks for; None when Lightning decides."""
    if isinstance(devices, bool):
        return None
    if isinstance(devices, int):
        return devices if devices > 0 else None
    if isinstance(devices, list | tuple):
        return len(devices)
    if isinstance(devices, str):
        text = devices.strip()
        if text.isdigit():
            return int(text)
        if "," in text:
            return len([d for d in text.split(",") if d.strip()])
    return None


def processes(trainer: Mapping[str, Any]) -> int:
    """How many processes a fit with these settings trains on (1 unless a multi-process
    strategy and a device count say more); their batches add up to one optimizer step."""
    strategy = trainer.get("strategy")
    if not isinstance(strategy, str) or not strategy.startswith(("ddp", "fsdp", "deepspeed")):
        return 1
    per_node = device_count(trainer.get("devices", "auto")) or 1
    return per_node * int(trainer.get("num_nodes", 1) or 1)


def log_interval(items: int, batch_size: int, trainer: Mapping[str, Any], cap: int) -> int:
    """``log_every_n_steps`` for a fit of ``items`` in batches of ``batch_size``: ``cap``, or
    every epoch when an epoch has fewer batches. Under DDP each process draws its share of
    the items, so its epoch is that many times shorter (Lightning warns of an interval longer
    than the epoch it sees)."""
    per_process = max(1, items // processes(trainer))
    return max(1, min(cap, per_process // max(1, batch_size)))  # floor: drop_last too


def result_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """The trainer settings that can change a fit's result (for cache keys, fingerprints)."""
    return {k: v for k, v in settings.items() if k not in NEUTRAL_TRAINER_KEYS}


class NonFiniteLoss(TactileBenchError):
    """A loss or a weight became NaN or infinite: training stopped, last good checkpoint kept."""


class ResumableSampler(Sampler[int]):
    """``RandomSampler(range(n), generator)`` with a restorable position.

    Share ``generator`` with the ``DataLoader`` (``generator=``) exactly as
    ``DataLoader(shuffle=True, generator=g)`` does, and the batches are the same;
    ``batch_size`` is the loader's, so a position counted in batches maps to samples.
    """

    def __init__(self, n: int, generator: torch.Generator, batch_size: int) -> None:
        self.generator = generator
        self.batch_size = batch_size
        self._inner = RandomSampler(range(n), generator=generator)
        self.epoch_state: torch.Tensor | None = None  # generator state when this epoch began
        self._resume: tuple[torch.Tensor, int] | None = None
        # (processes, rank) of the DDP fit it feeds (set by resumable_fit); see __iter__
        self.shard: tuple[int, int] = (1, 0)

    def __len__(self) -> int:
        return -(-len(self._inner) // self.shard[0])

    def resume(self, epoch_state: torch.Tensor, batches_done: int) -> None:
        """The next iteration replays the epoch that began at ``epoch_state`` from its
        batch ``batches_done``."""
        self._resume = (epoch_state, batches_done * self.batch_size)

    def next_epoch_state(self) -> torch.Tensor:
        """The generator state the next epoch will start from: the DataLoader draws one
        base seed from the shared generator when it creates an iterator, then we run."""
        probe = torch.Generator().set_state(self.generator.get_state())
        torch.empty((), dtype=torch.int64).random_(generator=probe)
        return probe.get_state()

    def __iter__(self) -> Iterator[int]:
        skip = 0
        if self._resume is not None:
            state, skip = self._resume
            self._resume = None
            self.generator.set_state(state)
        self.epoch_state = self.generator.get_state()
        order = iter(self._inner)
        replicas, rank = self.shard
        if replicas > 1:
            # under DDP each process draws the same permutation from its same-seeded
            # generator and takes its share as DistributedSampler does (pad by wrapping, then
            # every replicas-th); a restored position counts this process's batches
            full = list(order)
            full += full[: len(self) * replicas - len(full)]
            order = iter(full[rank::replicas])
        yield from islice(order, skip, None)


class PositionedSampler(Protocol):
    """What a checkpoint saves and restores of a fit's data position: a
    :class:`ResumableSampler`, or a group of them (``classify.stacked.SamplerGroup``)."""

    shard: tuple[int, int]

    @property
    def epoch_state(self) -> torch.Tensor | None: ...

    def next_epoch_state(self) -> torch.Tensor: ...

    def resume(self, epoch_state: torch.Tensor, batches_done: int) -> None: ...


class DeviceBatches:
    """The batches ``DataLoader(TensorDataset(*tensors), batch_size, sampler=sampler,
    generator=generator)`` gives, in the same order, drawn by indexing ``tensors`` where
    they are (an accelerator: moved there once, so no batch is copied from the host and no
    worker runs; Lightning's ``transfer_batch_to_device`` leaves a batch on its device).

    Each pass first draws the loader's base seed from ``generator``, as a ``DataLoader``
    iterator does, so the sampler's permutations, and ``ResumableSampler``'s positions, are
    the loader's.
    """

    def __init__(
        self,
        tensors: tuple[torch.Tensor, ...],
        sampler: Sampler[int],
        batch_size: int,
        generator: torch.Generator,
    ) -> None:
        self.tensors = tensors
        self.sampler = sampler
        self.batch_size = batch_size
        self.generator = generator

    def __len__(self) -> int:
        return -(-len(self.sampler) // self.batch_size)  # type: ignore[arg-type]

    def __iter__(self) -> Iterator[tuple[torch.Tensor, ...]]:
        torch.empty((), dtype=torch.int64).random_(generator=self.generator)
        device = self.tensors[0].device
        order = iter(self.sampler)
        while batch := list(islice(order, self.batch_size)):
            index = torch.tensor(batch, dtype=torch.long, device=device)
            yield tuple(t[index] for t in self.tensors)


def rng_states() -> dict[str, Any]:
    """Global torch (CPU, and every CUDA device's when there are any) / numpy / Python RNG
    states as plain types (``weights_only`` loadable)."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    version, state, py_gauss = random.getstate()
    states = {
        "torch": torch.get_rng_state(),
        "numpy": [kind, torch.from_numpy(keys.astype(np.int64)), pos, has_gauss, gauss],
        "python": [version, list(state), py_gauss],
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def set_rng_states(states: Mapping[str, Any]) -> None:
    """Inverse of :func:`rng_states`; a CUDA state is restored where CUDA is there to take
    it (a checkpoint written on a GPU resumes on a CPU with the CPU's states alone)."""
    torch.set_rng_state(states["torch"])
    if "cuda" in states and torch.cuda.is_available():
        cuda = list(states["cuda"])[: torch.cuda.device_count()]
        torch.cuda.set_rng_state_all(cuda)
    kind, keys, pos, has_gauss, gauss = states["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, gauss))
    version, state, py_gauss = states["python"]
    random.setstate((version, tuple(state), py_gauss))


def _float_tensors(outputs: Any) -> dict[str, torch.Tensor]:
    """The loss values a training_step returned (a tensor or a dict of them)."""
    if isinstance(outputs, torch.Tensor):
        return {"loss": outputs}
    if isinstance(outputs, Mapping):
        return {
            str(k): v
            for k, v in outputs.items()
            if isinstance(v, torch.Tensor) and v.is_floating_point()
        }
    return {}


def _first_bad_weight(module: torch.nn.Module) -> str | None:
    for name, tensor in module.state_dict().items():
        if tensor.is_floating_point() and not torch.isfinite(tensor).all():
            return name
    return None


class GuardedCheckpoint(Callback):
    """Saves ``path`` every ``every`` steps with the data position and RNG states, checks
    every loss and (before saving) every weight, and stops cleanly on Ctrl-C / SIGTERM."""

    def __init__(
        self,
        path: Path | None,
        every: int,
        sampler: PositionedSampler | None,
        fingerprint: str,
        what: str,
    ) -> None:
        self.path = Path(path) if path is not None else None  # None: guard only, never save
        self.every = max(1, int(every))
        self.sampler = sampler
        self.fingerprint = fingerprint
        self.what = what
        self.interrupted = False
        self._pending: list[tuple[str, int, torch.Tensor]] = []  # losses not yet checked
        self.saved_step: int | None = None
        self._next_save = self.every
        self._position: dict[str, Any] = {}

    @property
    def state_key(self) -> str:
        return "GuardedCheckpoint"

    # -------------------------------------------------------------- checkpoint content
    def state_dict(self) -> dict[str, Any]:
        return {
            "fingerprint": self.fingerprint,
            "rng": rng_states(),
            **self._position,
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        set_rng_states(state_dict["rng"])
        if self.sampler is not None and state_dict.get("epoch_state") is not None:
            self.sampler.resume(state_dict["epoch_state"], int(state_dict["skip"]))

    # -------------------------------------------------------------- hooks
    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        step = trainer.global_step
        self._next_save = (step // self.every + 1) * self.every

    def on_train_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
    ) -> None:
        losses = _float_tensors(outputs)
        step = trainer.global_step
        self._pending += [(name, step, value.detach()) for name, value in losses.items()]
        between = self._between_steps(trainer, batch_idx)
        due = self.path is not None and between and step >= self._next_save
        if pl_module.device.type == "cpu" or due or step % DEVICE_CHECK_EVERY == 0:
            self._check_losses(trainer)
            if not losses:  # manual optimisation that returns nothing: watch the weights
                self._check_weights(trainer, pl_module)
        if getattr(trainer, "received_sigterm", False):
            self.interrupted = True
        due = self.interrupted or step >= self._next_save
        if self.path is not None and due and between:
            self._save(trainer, pl_module, batch_idx)
            self._next_save = (step // self.every + 1) * self.every
        if self.interrupted and between:  # stop once the optimizer step is complete
            trainer.should_stop = True

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._check_losses(trainer)
        if self.path is None:
            return
        if not self.interrupted and self.saved_step != trainer.global_step:
            self._save(trainer, pl_module, None)

    # -------------------------------------------------------------- helpers
    @staticmethod
    def _between_steps(trainer: L.Trainer, batch_idx: int) -> bool:
        """Not in the middle of gradient accumulation (partial gradients are not saved)."""
        every = trainer.accumulate_grad_batches
        last = batch_idx + 1 >= trainer.num_training_batches
        return every <= 1 or (batch_idx + 1) % every == 0 or last

    def _check_losses(self, trainer: L.Trainer) -> None:
        """Fail on the first non-finite loss since the last check. On the CPU that is every
        step; on an accelerator every ``DEVICE_CHECK_EVERY`` steps and before every save, so
        the host waits for the device once per check, not once per step."""
        pending, self._pending = self._pending, []
        if not pending:
            return
        means = torch.stack([value.float().mean() for _, _, value in pending])
        finite = torch.isfinite(means).tolist()
        if all(finite):
            return
        first = finite.index(False)
        name, step, _ = pending[first]
        self._fail(trainer, f"{name} = {float(means[first])}", step)

    def _check_weights(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        bad = _first_bad_weight(pl_module)
        if bad is not None:
            self._fail(trainer, f"weight {bad} is not finite")

    def _fail(self, trainer: L.Trainer, problem: str, step: int | None = None) -> None:
        kept = (
            f"the last good checkpoint ({self.path}, step {self.saved_step}) is kept"
            if self.saved_step is not None
            else "no checkpoint had been saved yet"
        )
        raise NonFiniteLoss(
            f"{self.what}: {problem} at step {trainer.global_step if step is None else step}; "
            f"training stopped, {kept}. "
            "Lower the learning rate or check the data"
        )

    def _save(
        self, trainer: L.Trainer, pl_module: L.LightningModule, batch_idx: int | None
    ) -> None:
        assert self.path is not None
        self._check_weights(trainer, pl_module)
        if self.sampler is not None and batch_idx is not None:
            done = batch_idx + 1
            if done >= trainer.num_training_batches:  # epoch over: the next one starts fresh
                self._position = {"epoch_state": self.sampler.next_epoch_state(), "skip": 0}
            else:
                self._position = {"epoch_state": self.sampler.epoch_state, "skip": done}
        # weights_only=False said, not defaulted: resume needs optimizer and callback state,
        # and Lightning logs "`weights_only` was not set" at every save otherwise
        trainer.save_checkpoint(self.path, weights_only=False)
        self.saved_step = trainer.global_step
        log.debug("%s: checkpoint at step %d -> %s", self.what, self.saved_step, self.path)


@dataclass
class FitReport:
    """What happened in a fit: the step it resumed from (None: from scratch), where it ended."""

    resumed_from_step: int | None
    global_step: int
    checkpoint: Path


def _moments(x: torch.Tensor, chunk: int = 1 << 20) -> tuple[float, float]:
    """Sum and sum of squares of ``x`` in float64, a chunk at a time.

    A float64 copy of a whole training set and of its square (10.7k 64 x 64 RGB images:
    0.9 GB each) would double a classifier stage's peak memory for a fingerprint.
    """
    total = squares = 0.0
    for part in x.detach().reshape(-1).split(chunk):
        p = part.double()
        total += float(p.sum())
        squares += float((p * p).sum())
    return total, squares


def fingerprint(*parts: Any) -> str:
    """Hash of what a checkpoint must agree with to be resumed (config, data, settings)."""

    def plain(x: Any) -> Any:
        if isinstance(x, torch.Tensor):
            return ["tensor", list(x.shape), *_moments(x)]
        if isinstance(x, Mapping):
            return {str(k): plain(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [plain(v) for v in x]
        return x if isinstance(x, str | int | float | bool | type(None)) else repr(x)

    return json_sha256(plain(list(parts)))[:16]


def _usable_checkpoint(path: Path, expected: str, what: str) -> int | None:
    """The step of a checkpoint we can resume from, or None (a bad one is removed, with a
    warning: a truncated or foreign file must never be used)."""
    if not path.exists():
        return None
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        state = ckpt["callbacks"]["GuardedCheckpoint"]
        step = int(ckpt["global_step"])
        found = state["fingerprint"]
    except Exception as exc:  # truncated zip, foreign pickle, missing keys: all unusable
        reason = str(exc).strip().splitlines()[0][:100] if str(exc).strip() else type(exc).__name__
        log.warning("%s: checkpoint %s is unreadable (%s); starting over", what, path, reason)
        path.unlink()
        return None
    if found != expected:
        log.warning("%s: checkpoint %s is of another fit; starting over", what, path)
        path.unlink()
        return None
    return step


def _launched_shard(settings: Mapping[str, Any]) -> tuple[int, int]:
    """(processes, rank) of a fit over the processes of a launch that started before it
    (torchrun, srun, ``tactile_bench.pipeline.launch``): the process group exists and the
    settings ask for more than one device. (1, 0) for any other fit, a spawn strategy's too
    (its processes start inside ``fit``, after this)."""
    import torch.distributed as dist

    if not (dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1):
        return 1, 0
    if settings.get("devices", 1) in (1, "1") and int(settings.get("num_nodes", 1) or 1) == 1:
        return 1, 0
    return dist.get_world_size(), dist.get_rank()


def _resume_point_of_rank_zero(step: int | None, path: Path) -> tuple[int | None, Path]:
    """Every rank of a launch resumes from where rank 0 does, from rank 0's file (the others
    never write checkpoints, and must take as many steps)."""
    import torch.distributed as dist

    box: list[Any] = [(step, str(path))]
    dist.broadcast_object_list(box, src=0)
    return box[0][0], Path(box[0][1])


@contextmanager
def _stop_on_sigint(guard: GuardedCheckpoint) -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if guard.interrupted:  # second Ctrl-C: stop now
            raise KeyboardInterrupt
        guard.interrupted = True
        log.warning(
            "%s: Ctrl-C, stopping after this step and saving a checkpoint "
            "(press again to abort at once)",
            guard.what,
        )

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


#: the start of the notice every ``lightning.Trainer`` without a LitLogger logs (an
#: advertisement for Lightning's cloud service; no Trainer argument turns it off)
LITLOGGER_TIP = "💡 Tip: For seamless cloud logging"
#: the logger Lightning's ``rank_zero_info`` writes to
RANK_ZERO_LOGGER = "lightning.pytorch.utilities.rank_zero"
#: torch 2.13 deprecates ``LeafSpec``, which Lightning's ``_pytree`` still builds at every
#: fit; a notice to Lightning's developers, not to our users
LEAFSPEC_DEPRECATION = r"`isinstance\(treespec, LeafSpec\)` is deprecated"
#: Lightning's hint to add DataLoader workers, given at every fit on a many-core machine
FEW_WORKERS_HINT = r"The '\w+_dataloader' does not have many workers"


#: what Lightning logs at every Trainer and fit, once per training (a recipe's 25 trainings
#: printed 75 to 100 such lines between the stages' own). Each stage logs its own line
#: naming the device and precision it runs in instead (``pipeline.runner``)
ROUTINE_NOTICES = (
    "Using bfloat16 Automatic Mixed Precision",
    "Using 16bit Automatic Mixed Precision",
    LITLOGGER_TIP,
    "GPU available: ",
    "TPU available: ",
    "HPU available: ",
    "LOCAL_RANK: ",
    "`Trainer.fit` stopped: ",
)


class _DropRoutineNotices(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(ROUTINE_NOTICES)


@contextmanager
def lightning_notices_off() -> Iterator[None]:
    """Keep routine third-party notices out of a fit's output, and only those: Lightning's
    litlogger tip and its no-accelerator and fit-stopped lines (``ROUTINE_NOTICES``, filtered
    on the logger that writes them) and torch's ``LeafSpec`` deprecation raised inside
    Lightning (filtered by exact message and module). Every other warning and log line still
    shows."""
    logger = logging.getLogger(RANK_ZERO_LOGGER)
    notices = _DropRoutineNotices()
    logger.addFilter(notices)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings(
                "ignore",
                message=LEAFSPEC_DEPRECATION,
                category=FutureWarning,
                module=r"lightning\.pytorch\.utilities\._pytree",
            )
            # the data are tensors in memory: loader workers would only copy them
            warnings.filterwarnings("ignore", message=FEW_WORKERS_HINT)
            yield
    finally:
        logger.removeFilter(notices)


def _share_tensors_through_files(strategy: Any) -> None:
    """Spawned DDP workers receive the data through shared memory; torch's default passes
    file descriptors, which fail in containers ("unable to resize file"). Files in
    /dev/shm work everywhere, so spawn strategies use them."""
    if isinstance(strategy, str) and "spawn" in strategy:
        torch.multiprocessing.set_sharing_strategy("file_system")


def resumable_fit(
    module: L.LightningModule,
    settings: dict[str, Any],
    checkpoint_dir: Path,
    sampler: PositionedSampler | None,
    fit_fingerprint: str,
    what: str,
    **fit_kwargs: Any,
) -> FitReport:
    """``L.Trainer(**settings).fit(module, **fit_kwargs)``, resumable and guarded.

    ``settings`` are Trainer arguments plus optionally ``checkpoint_every_n_steps``;
    ``what`` names the fit in messages. Raises ``KeyboardInterrupt`` after a clean stop.
    """
    settings = dict(settings)
    use_tensor_cores()
    every = int(settings.pop(EVERY_KEY, DEFAULT_EVERY))
    save = bool(settings.pop("enable_checkpointing", True))  # False: no files (benchmarks)
    settings["enable_checkpointing"] = False  # Lightning's own ModelCheckpoint: not needed
    path = Path(checkpoint_dir) / CHECKPOINT_NAME
    guard = GuardedCheckpoint(path if save else None, every, sampler, fit_fingerprint, what)
    settings["callbacks"] = [guard, *(settings.get("callbacks") or [])]
    step = None
    if save:
        path.parent.mkdir(parents=True, exist_ok=True)
        step = _usable_checkpoint(path, fit_fingerprint, what)
    shard = _launched_shard(settings)
    if shard[0] > 1:
        step, path = _resume_point_of_rank_zero(step, path)
        if sampler is not None:  # Lightning's wrapper of it would lose the restored position
            sampler.shard = shard
            settings["use_distributed_sampler"] = False
    if step is not None:
        log.info("%s: resuming from %s (step %d)", what, path, step)
    _share_tensors_through_files(settings.get("strategy"))
    with lightning_notices_off():
        trainer = L.Trainer(**settings)
    with _stop_on_sigint(guard), lightning_notices_off(), warnings.catch_warnings():
        # Lightning cannot see that our sampler resumes mid-epoch exactly; its warning is moot
        warnings.filterwarnings("ignore", message="You're resuming from a checkpoint that ended")
        try:
            trainer.fit(
                module,
                ckpt_path=str(path) if step is not None else None,
                weights_only=True,
                **fit_kwargs,
            )
        except SystemExit:  # Lightning's own Ctrl-C handler exits; make it an interrupt
            raise KeyboardInterrupt from None
    if guard.interrupted:
        kept = f"checkpoint {path} kept" if save else "checkpoints are off"
        log.warning("%s: stopped at step %d; %s", what, trainer.global_step, kept)
        raise KeyboardInterrupt
    return FitReport(step, trainer.global_step, path)
