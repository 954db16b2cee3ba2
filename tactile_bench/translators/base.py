"""The one interface every translator (built-in or plugin) implements.

A translator turns simulated contact depth into a tactile image of a real
sensor. It is a LightningModule so that fitting it is an ordinary Lightning
fit (loggers, checkpoints, precision, strategies all come for free), and it is
fitted on background-free pairs: (depth, real foreground), where foreground =
(image - no-contact image) / 255 + 0.5 as in the paper's code. At inference
any sensor's background is added back, so one model serves every unit.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any, ClassVar

import lightning as L
import torch
from lightning.pytorch.loggers import Logger
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from torch.utils.data import DataLoader, TensorDataset

import tactile_bench

# the pixel conventions live in the data layer; re-exported here for translators and plugins
from tactile_bench.data.pixels import foreground_to_image as foreground_to_image
from tactile_bench.data.pixels import image_to_foreground as image_to_foreground
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.files import require_not_special
from tactile_bench.hardware import Precision, trainer_precision
from tactile_bench.io import atomic_torch_save
from tactile_bench.training import (
    FitReport,
    ResumableSampler,
    fingerprint,
    log_interval,
    result_settings,
    resumable_fit,
)

CHECKPOINT_FORMAT = 1


class TranslatorConfig(BaseModel):
    """Base of every translator's typed config: unknown keys are errors, not silently ignored.

    ``precision`` is the fit's Lightning precision (a recipe's ``trainer: {precision: ...}``
    overrides it); ``auto`` is bf16 autocast only where the hardware has bf16 arithmetic
    (``tactile_bench.hardware``), since elsewhere bf16 is emulated and many times slower.
    Translators that sample with networks may also use it at inference (``diffusion`` does).
    """

    model_config = ConfigDict(extra="forbid")
    seed: int = Field(default=0, description="seed of the fit's data order and random draws")
    batch_size: int = Field(default=32, ge=1, description="pairs a training step")
    max_steps: int = Field(default=200, ge=0, description="training steps of a fit; 0: none")
    precision: Precision = Field(
        default="auto", description="auto: bf16 where the CPU has bf16 arithmetic, else fp32"
    )


def _why_unreadable(exc: Exception) -> str:
    """A short reason for a failed ``torch.load`` (torch's own messages run to paragraphs)."""
    text = str(exc)
    if "central directory" in text or "zip archive" in text or isinstance(exc, EOFError):
        return "truncated or corrupt: not a complete torch zip archive"
    if isinstance(exc, pickle.UnpicklingError) or "Weights only load failed" in text:
        return "its content is not a tensors-and-plain-values checkpoint"
    first = text.strip().splitlines()[0][:100] if text.strip() else type(exc).__name__
    return f"corrupt or truncated? {first}"


class Translator(L.LightningModule):
    """Depth (N, 1, S, S) in mm -> tactile image (N, 3, S, S) in 0..255.

    Subclasses set ``name``, ``Config`` and implement ``translate_foreground``.
    Learning translators also implement ``training_step`` and
    ``configure_optimizers``; ``trainable = False`` marks those with nothing to fit.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[TranslatorConfig]] = TranslatorConfig
    trainable: ClassVar[bool] = True

    def __init__(self, config: TranslatorConfig | dict[str, Any] | None = None) -> None:
        super().__init__()
        self.config = self.parse_config(config)

    @classmethod
    def parse_config(cls, config: TranslatorConfig | dict[str, Any] | None) -> TranslatorConfig:
        """Validate a config dict against the translator's schema, naming the bad key."""
        if isinstance(config, cls.Config):
            return config
        try:
            return cls.Config(**(config or {}))
        except ValidationError as exc:
            first = exc.errors()[0]
            key = ".".join(str(part) for part in first["loc"])
            where = f"config key {key!r}: " if key else ""  # a whole-config check names its keys
            message = first["msg"].removeprefix("Value error, ")
            raise TactileBenchError(f"translator {cls.name!r}: {where}{message}") from None

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Depth -> foreground (N, 3, S, S) around 0.5; the part each translator defines."""
        raise NotImplementedError

    def training_precision(self, trainer: dict[str, Any] | None = None) -> Any:
        """The Lightning precision ``fit_pairs`` trains in with these ``trainer`` settings:
        theirs when they set one, else the config's, with ``auto`` resolved for the device."""
        return trainer_precision(trainer or {}, self.config.precision)

    def inference_precision(self) -> str:
        """The precision ``translate`` computes in: fp32 unless a translator autocasts."""
        return "32-true"

    def fit_pairs(
        self,
        depth: torch.Tensor,
        foreground: torch.Tensor,
        out_dir: Path,
        trainer: dict[str, Any] | None = None,
        loggers: list[Logger] | None = None,
    ) -> FitReport | None:
        """Fit on (depth, real foreground) pairs with a Lightning Trainer.

        ``trainer`` passes straight through to ``lightning.Trainer`` (accelerator,
        devices, strategy, precision ...), so the same call scales out; without a
        ``precision`` there, the config's applies (``auto``: see ``hardware``); its extra key
        ``checkpoint_every_n_steps`` sets how often ``out_dir/checkpoints/last.ckpt`` is
        written. A fit that finds that checkpoint resumes from it (see ``training``).
        """
        if not self.trainable or self.config.max_steps == 0:
            return None
        L.seed_everything(self.config.seed, workers=True, verbose=False)
        generator = torch.Generator().manual_seed(self.config.seed)
        sampler = ResumableSampler(len(depth), generator, self.config.batch_size)
        loader = DataLoader(
            TensorDataset(depth.float(), foreground.float()),
            batch_size=self.config.batch_size,
            sampler=sampler,
            drop_last=len(depth) > self.config.batch_size,
            generator=generator,
        )
        settings: dict[str, Any] = {
            "max_steps": self.config.max_steps,
            "max_epochs": -1,
            "logger": loggers if loggers is not None else False,
            "enable_model_summary": False,
            "default_root_dir": str(out_dir),
        }
        settings.update(trainer or {})
        # an epoch of a small fine-tuning pool has fewer batches than 10: log every epoch
        settings.setdefault(
            "log_every_n_steps", log_interval(len(depth), self.config.batch_size, settings, 10)
        )
        settings["precision"] = self.training_precision(settings)
        config = self.config.model_dump(mode="json")
        start = self.state_dict()  # fine-tuning: the weights it starts from matter too
        key = fingerprint(self.name, config, result_settings(settings), depth, foreground, start)
        return resumable_fit(
            self,
            settings,
            Path(out_dir) / "checkpoints",
            sampler,
            key,
            f"translator {self.name!r} fit in {out_dir}",
            train_dataloaders=loader,
        )

    def fit_diagnostics(self) -> dict[str, Any]:
        """Figures about how the last fit went (e.g. a GAN's ``divergence``); {} by default."""
        return {}

    @torch.no_grad()
    def translate(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Depth plus any sensor's no-contact frame -> image in 0..255, on ``depth``'s device.

        The translator computes on its own device (``.to(device)`` moves it); random draws
        come from ``generator`` on the CPU, so a seed gives the same draws on every device.
        """
        was_training = self.training
        self.eval()
        try:
            foreground = self.translate_foreground(depth.to(self.device), generator).float()
        finally:
            self.train(was_training)
        image = foreground_to_image(foreground, background.float().to(foreground.device))
        return image.to(depth.device)

    def save(self, path: str | Path) -> Path:
        """Write config and weights atomically, tagged with the translator name and format."""
        payload = {
            "translator": self.name,
            "format": CHECKPOINT_FORMAT,
            "tactile_bench": tactile_bench.__version__,
            "config": self.config.model_dump(mode="json"),
            "state_dict": {k: v.detach().cpu() for k, v in self.state_dict().items()},
        }
        return atomic_torch_save(payload, Path(path))

    @classmethod
    def load(cls, path: str | Path) -> Translator:
        """Load a checkpoint written by ``save``; anything else is a one-line error naming it."""
        path = Path(path)
        require_not_special(path, "translator checkpoint")  # a FIFO would block torch.load
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise TactileBenchError(f"{path}: translator checkpoint not found") from None
        except IsADirectoryError:
            raise TactileBenchError(f"{path}: is a folder, not a translator checkpoint") from None
        except Exception as exc:  # corrupt, truncated or foreign file: one line, not a traceback
            raise TactileBenchError(
                f"{path}: not a readable translator checkpoint ({_why_unreadable(exc)})"
            ) from None
        if not isinstance(payload, dict) or "translator" not in payload:
            raise TactileBenchError(f"{path}: not a tactile_bench translator checkpoint")
        if payload["translator"] != cls.name:
            raise TactileBenchError(
                f"{path}: checkpoint of translator {payload['translator']!r}, not {cls.name!r}"
            )
        found = payload.get("format")
        if found != CHECKPOINT_FORMAT:
            newer = isinstance(found, int) and found > CHECKPOINT_FORMAT
            age = "newer" if newer else "older"
            by = f", written by tactile_bench {payload['tactile_bench']}" * (
                "tactile_bench" in payload
            )
            raise TactileBenchError(
                f"{path}: checkpoint format {found!r}{by} is {age} than the format "
                f"{CHECKPOINT_FORMAT} tactile_bench {tactile_bench.__version__} reads"
            )
        try:
            translator = cls(payload["config"])
        except TactileBenchError as exc:
            raise TactileBenchError(f"{path}: {exc}") from None
        except (KeyError, TypeError) as exc:
            raise TactileBenchError(f"{path}: checkpoint lacks a valid config ({exc})") from None
        try:
            translator.load_state_dict(payload["state_dict"])
        except (KeyError, TypeError, RuntimeError) as exc:
            first = str(exc).strip().splitlines()[0][:160]
            raise TactileBenchError(
                f"{path}: weights do not fit translator {cls.name!r} ({first})"
            ) from None
        return translator
