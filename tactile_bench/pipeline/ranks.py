"""A recipe's stages across the ranks of a launch (``pipeline.launch``): leader and followers.

The leader (global rank 0) decides, stage by stage, what is cached and what runs, exactly as
one process does (``runner.start``); for a stage to run it sends the stage and its context
to the followers only when the stage trains (``StageKind.fits``): then every rank runs it and
the fits inside are Lightning DDP fits over all of them. Any other stage runs on the leader,
with its trainer settings for one process, while the followers wait for the next message.
Stages run one at a time (``jobs`` is 1 under a launch: DDP already uses every device).

Messages, leader to followers: ``("fit", stage, ctx)``, ``("end",)``, ``("stop", reason)``.
A leader that fails sends ``stop`` (each follower then exits with one line), unless the
failure is a lost process, when there is no one to tell.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.launch import Launch, scratch_dir, share, single_process_trainer
from tactile_bench.pipeline.recipe import Stage
from tactile_bench.pipeline.side_by_side import Ran, execute
from tactile_bench.pipeline.stages.base import StageContext

log = logging.getLogger("tactile_bench")


class LostProcess(TactileBenchError):
    """Another process of the launch is gone: the one line rank 0 ends the launch with."""


def lost_process_error(stage: str, exc: BaseException) -> LostProcess | None:
    """The one line for a collective that failed because another rank is gone (killed,
    out of memory, its node lost); None for any other error."""
    from torch.distributed import DistError

    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    text = re.sub(r"^\[[^\]]*\]\s*", "", text)[:160]  # gloo's source location first
    gone = ("Connection closed by peer", "Connection reset", "Broken pipe", "Socket Timeout")
    if isinstance(exc, DistError) or any(word in text for word in gone):
        return LostProcess(
            f"stage {stage}: a process of this launch was lost ({text}); finished stages "
            "and the last training checkpoint are kept, rerun the same launch to resume"
        )
    return None


@contextmanager
def sigterm_ends_launch() -> Iterator[None]:
    """On rank 0: a SIGTERM (what torchrun sends the others when one process of the launch
    ends, and SLURM at a job's time limit or cancel) ends the run with one line instead of
    killing it silently. Every write is atomic, so nothing is left half-written."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise LostProcess(
            "the launch was stopped (SIGTERM from its launcher: another of its processes "
            "ended, or the job was cancelled or ran out of time); finished stages and the "
            "last training checkpoint are kept, rerun the same launch to resume"
        )

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def lead(
    launch: Launch,
    stages: list[Stage],
    start: Callable[[Stage, dict[str, Any]], tuple[Any, StageContext | None]],
    finish: Callable[[Stage, Any, Ran], Any],
) -> dict[str, Any]:
    """On global rank 0: every stage's result, in order (``start``/``finish`` as for
    ``side_by_side.run_side_by_side``)."""
    results: dict[str, Any] = {}
    for stage in stages:
        handle, ctx = start(stage, results)
        if ctx is None:
            results[stage.name] = handle
            continue
        if stage.kind.fits:
            log.info("stage %s: training on all %d processes", stage.name, launch.world_size)
            share(launch, ("fit", stage, ctx))
        else:
            ctx = dataclasses.replace(ctx, trainer=single_process_trainer(ctx.trainer))
        try:
            ran = execute(stage, ctx)
        except (RuntimeError, OSError) as exc:
            lost = lost_process_error(stage.name, exc)
            if lost is None:
                raise
            raise lost from None
        results[stage.name] = finish(stage, handle, ran)
    share(launch, ("end",))
    return results


def stop_followers(launch: Launch, reason: str, wait_s: float = 10.0) -> None:
    """Tell the followers the leader failed. Best effort, for at most ``wait_s``: a follower
    inside a fit's collective does not read the message, and ends when the leader exits."""

    def tell() -> None:
        try:
            share(launch, ("stop", reason.splitlines()[0][:300] if reason else "failed"))
        except Exception:  # noqa: BLE001 - the launch is broken already; rank 0's error stands
            log.debug("rank 0: could not tell the other ranks to stop")

    teller = threading.Thread(target=tell, name="stop-followers", daemon=True)
    teller.start()
    teller.join(wait_s)


def follow(launch: Launch) -> None:
    """On every other rank: run the stages the leader sends, until it says the end."""
    while True:
        message = share(launch)
        if message[0] == "end":
            return
        if message[0] == "stop":
            raise TactileBenchError(
                f"{launch.describe()}: stopped with rank 0 (its error says why)"
            )
        _, stage, ctx = message
        with scratch_dir(launch, stage.name) as folder:
            trainer = {**ctx.trainer, "enable_progress_bar": False}
            ctx = dataclasses.replace(ctx, directory=folder, progress=False, trainer=trainer)
            try:
                execute(stage, ctx)
            except (RuntimeError, OSError) as exc:
                lost = lost_process_error(stage.name, exc)
                if lost is None:
                    raise
                raise lost from None
