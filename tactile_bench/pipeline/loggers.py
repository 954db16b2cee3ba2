"""Experiment loggers: a CSV logger always, plus Weights & Biases offline when available.

Our machines have no network and no wandb account, so wandb must never prompt or try to
connect: it runs in offline mode under ``save_dir`` (``wandb sync`` uploads later). Set
``TACTILE_BENCH_NO_WANDB=1`` to skip it entirely (e.g. in CI, or to save its 1.5 s start).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Iterable
from pathlib import Path

from lightning.pytorch.loggers import CSVLogger, Logger

NO_WANDB_ENV = "TACTILE_BENCH_NO_WANDB"
WANDB_PROJECT = "tactile_bench"


def wandb_enabled(requested: bool = True) -> bool:
    """True if wandb is requested, not disabled by the environment, and importable."""
    if not requested or os.environ.get(NO_WANDB_ENV, "").strip().lower() in {"1", "true", "yes"}:
        return False
    return importlib.util.find_spec("wandb") is not None


def make_loggers(save_dir: Path, name: str, wandb: bool = True) -> list[Logger]:
    """Loggers for one run: ``CSVLogger(save_dir, name)`` and, if enabled, an offline wandb run.

    The wandb run writes under ``save_dir/wandb/offline-run-*``. Call :func:`finish_loggers`
    when the run is over: wandb keeps one active run per process, and a later WandbLogger
    would otherwise attach to it.
    """
    save_dir = Path(save_dir)
    save_dir.mkdir(parents=True, exist_ok=True)
    loggers: list[Logger] = [CSVLogger(save_dir=str(save_dir), name=name)]
    if wandb_enabled(wandb):
        from lightning.pytorch.loggers import WandbLogger

        # Offline unless the user explicitly asked for online; never prompt, never log in.
        if os.environ.get("WANDB_MODE", "").lower() != "online":
            os.environ["WANDB_MODE"] = "offline"
        os.environ.setdefault("WANDB_SILENT", "true")
        os.environ.setdefault("WANDB_CONSOLE", "off")
        os.environ["WANDB_DIR"] = str(save_dir)
        offline = os.environ["WANDB_MODE"] != "online"
        logger = WandbLogger(
            name=name,
            save_dir=str(save_dir),
            project=os.environ.get("WANDB_PROJECT", WANDB_PROJECT),
            offline=offline,
            mode="offline" if offline else "online",
        )
        # Lightning always passes anonymous=None, which wandb >= 0.19 warns is deprecated.
        init_kwargs = getattr(logger, "_wandb_init", None)
        if isinstance(init_kwargs, dict) and init_kwargs.get("anonymous") is None:
            init_kwargs.pop("anonymous", None)
        loggers.append(logger)
    return loggers


def finish_loggers(loggers: Iterable[Logger]) -> None:
    """Flush every logger and close the wandb run (if one was started) so the next can start."""
    for logger in loggers:
        logger.finalize("success")
        if type(logger).__name__ == "WandbLogger" and getattr(logger, "_experiment", None):
            logger.experiment.finish()
            logger._experiment = None  # a later use would otherwise write to a finished run
