"""The ``diffusion`` translator: the paper's conditional DDPM, as a Lightning module.

Spaces (fixed, so a checkpoint means the same thing everywhere):
- condition c = depth_mm / ``depth_scale_mm`` (1 mm: braille presses are 0 .. ~1.5 mm);
- sample x = (foreground - 0.5) * ``foreground_scale``. A foreground is the no-contact frame
  plus small deviations (a DIGIT contact moves pixels by at most ~+-60 / 255, i.e. +-0.25),
  so k = 4 maps the strongest contact signal to about +-1, the range DDPM's noise schedule
  assumes. x0 predictions are clipped to what a foreground can be (0..1, i.e. +-k/2).

Pixel noise: a real camera adds noise that no depth image predicts. An x0-predicting network
returns the mean image given the condition, and a few-step sampler never re-adds what the
mean removed, so samples came out cleaner than any real frame (high-pass energy 0.74 against
1.46 grey levels on braille) and a classifier trained on them read real frames at 14%.
With ``observation_noise`` (default) the translator estimates that noise per colour
channel from its own training images (frame to frame, averaged over training batches) and
adds it, white, to every sample: the last step of sampling from
p(image | depth), not a parameter of any simulator.
"""

from __future__ import annotations

import copy
import json
import statistics
import time
from pathlib import Path
from typing import Any, Literal

import torch
import torch.nn.functional as F
from diffusers import DDPMScheduler, UNet2DModel
from pydantic import Field

from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import resolve_precision
from tactile_bench.metrics.noise import estimate_pixel_noise
from tactile_bench.translators.base import CHECKPOINT_FORMAT, Translator, TranslatorConfig
from tactile_bench.translators.diffusion.sampling import (
    SAMPLERS,
    TARGETS,
    make_sampler,
    sample,
    training_scheduler,
)
from tactile_bench.translators.diffusion.torch_model import PRESETS, build_unet, conditional_output

PRETRAINED_CONFIG = "tactile_bench.json"


#: images sampled at a time, at least, on an accelerator
DEVICE_SAMPLE_BATCH = 1024


class DiffusionConfig(TranslatorConfig):
    """Paper schedule and network input; defaults chosen for a CPU budget (measured).

    The paper's exact setting is ``prediction: epsilon, sampler: ddpm, steps: 500``. With
    epsilon prediction the fast solvers (DDIM, DPM-Solver++) failed after a few hundred steps
    of training (SSIM 0.07-0.19 vs 0.89 for DDPM-500), while x0 prediction (``sample``) gave
    SSIM 0.996 with DPM-Solver++ at 10-20 steps, 25-50x cheaper: so ``sample`` is the default.
    EMA lagged behind the raw weights in such short runs, so it is off by default.

    Sampling defaults (``python -m tactile_bench bench``, docs/results/bench.md): with x0
    prediction every solver step is already a denoised estimate, and on the braille test set
    DPM-Solver++ keeps DDPM-500's SSIM from 1 step up; 4 steps (two second-order steps
    between first-order ones) are over 100x faster than DDPM-500 on the same network.
    channels_last activations and chunks of 32 images (which stay in cache; 128 were slower)
    each add speed at inference, and so does bf16 autocast where the CPU has bf16 arithmetic
    (AVX-512-BF16, AMX): ``precision: auto`` (inherited) trains and samples in bf16 there and
    in fp32 elsewhere, where emulated bf16 is 50-100x slower. ``bf16: true/false``, the key before
    ``precision``, still loads: true (its old default) as ``auto``, false as ``32-true``.
    """

    max_steps: int = Field(default=1000, ge=0, description="training steps")
    lr: float = Field(default=1e-4, gt=0, description="Adam learning rate")
    preset: Literal[tuple(PRESETS)] = Field(  # type: ignore[valid-type]
        default="cpu-small", description="U-Net size (torch_model.PRESETS)"
    )
    image_size: int = Field(default=64, ge=8, description="image side in pixels")
    train_timesteps: int = Field(
        default=500, ge=2, description="noise levels of the training schedule (the paper: 500)"
    )
    beta_start: float = Field(default=1e-4, description="noise variance at the first timestep")
    beta_end: float = Field(default=0.02, description="noise variance at the last timestep")
    prediction: Literal[tuple(TARGETS)] = Field(  # type: ignore[valid-type]
        default="sample", description="what the network predicts: sample (x0) or epsilon"
    )
    sampler: Literal[tuple(SAMPLERS)] = Field(  # type: ignore[valid-type]
        default="dpmsolver++", description="sampling scheduler (the paper: ddpm)"
    )
    steps: int = Field(default=4, ge=1, description="sampling steps (the paper: 500)")
    sample_batch_size: int = Field(default=32, ge=1, description="images sampled at a time")
    depth_scale_mm: float = Field(
        default=1.0, gt=0, description="the condition is depth in mm divided by this"
    )
    foreground_scale: float = Field(
        default=4.0, gt=0, description="sample = (foreground - 0.5) times this"
    )
    ema: bool = Field(default=False, description="sample with an EMA of the weights")
    ema_decay: float = Field(default=0.999, ge=0.0, lt=1.0, description="decay of that EMA")
    channels_last: bool = Field(default=True, description="channels_last memory layout")
    observation_noise: bool = Field(
        default=True, description="add the camera noise measured on the training images"
    )


_NOISE_DECAY = 0.98  # the estimate averages over about the last 50 training batches


class DiffusionTranslator(Translator):
    """Depth -> foreground by conditional denoising from pure noise."""

    name = "diffusion"
    Config = DiffusionConfig

    def __init__(self, config: DiffusionConfig | dict[str, Any] | None = None) -> None:
        super().__init__(config)
        cfg = self.config
        with torch.random.fork_rng(devices=[]):  # same seed -> same initial weights
            torch.manual_seed(cfg.seed)
            self.unet = build_unet(PRESETS[cfg.preset], cfg.image_size)
        self.noise_scheduler = training_scheduler(
            cfg.train_timesteps,
            cfg.beta_start,
            cfg.beta_end,
            clip_range=cfg.foreground_scale / 2,
            prediction_type=cfg.prediction,
        )
        # observation noise: running average of per-batch estimates, with its update count
        self.register_buffer("pixel_noise_avg", torch.zeros(3))
        self.register_buffer("pixel_noise_updates", torch.zeros((), dtype=torch.long))
        self.ema_unet: UNet2DModel | None = None
        if cfg.ema:
            self.ema_unet = copy.deepcopy(self.unet).requires_grad_(False)
            self.register_buffer("ema_updates", torch.zeros((), dtype=torch.long))

    # --- spaces -----------------------------------------------------------------------------
    def condition(self, depth: torch.Tensor) -> torch.Tensor:
        return depth.float() / self.config.depth_scale_mm

    def to_sample_space(self, foreground: torch.Tensor) -> torch.Tensor:
        return (foreground.float() - 0.5) * self.config.foreground_scale

    def to_foreground(self, x: torch.Tensor) -> torch.Tensor:
        return (x / self.config.foreground_scale + 0.5).clamp(0.0, 1.0)

    def inference_precision(self) -> str:
        """The config's precision resolved for the device sampling runs on."""
        return resolve_precision(self.config.precision, self.device.type)

    def _autocast(self) -> torch.autocast:
        """bf16 autocast for sampling iff the resolved precision is bf16. Training has none
        of its own: the Trainer's precision (``fit_pairs``) autocasts the whole step, so an
        explicit ``trainer: {precision: ...}`` is never undone by a nested autocast here."""
        device = self.device.type
        enabled = self.inference_precision() == "bf16-mixed" and device in ("cpu", "cuda")
        autocast_device = device if device in ("cpu", "cuda") else "cpu"  # meta: shapes only
        return torch.autocast(autocast_device, torch.bfloat16, enabled=enabled)

    @property
    def inference_unet(self) -> UNet2DModel:
        """The EMA weights when kept, else the trained ones."""
        return self.ema_unet if self.ema_unet is not None else self.unet

    # --- training ---------------------------------------------------------------------------
    def training_step(
        self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int
    ) -> torch.Tensor:
        depth, foreground = batch
        x0 = self.to_sample_space(foreground)
        noise = torch.randn_like(x0)
        t = torch.randint(0, self.config.train_timesteps, (len(x0),), device=x0.device)
        noisy = self.noise_scheduler.add_noise(x0, noise, t)
        target = TARGETS[self.config.prediction](self.noise_scheduler, x0, noise, t)
        # No autocast of our own: under bf16-mixed the Trainer autocasts the whole step (one
        # switch, the fit's precision); of these ops only the network's convs and linears cast.
        output = conditional_output(self.unet, noisy, self.condition(depth), t)
        loss = F.mse_loss(output.float(), target)
        self.log("train_loss", loss, prog_bar=True, batch_size=len(x0))
        if self.config.observation_noise:
            with torch.autocast(self.device.type, enabled=False):  # an fp32 statistic
                self._track_pixel_noise(foreground)
        return loss

    @torch.no_grad()
    def _track_pixel_noise(self, foreground: torch.Tensor) -> None:
        estimate = estimate_pixel_noise(foreground)
        if estimate is None or estimate.shape != self.pixel_noise_avg.shape:
            return  # too few frames, or not RGB
        self.pixel_noise_avg.lerp_(estimate, 1.0 - _NOISE_DECAY)
        self.pixel_noise_updates += 1

    @property
    def pixel_noise_std(self) -> torch.Tensor:
        """Per-channel noise std (3,) in foreground units added to samples (zeros if none)."""
        n = int(self.pixel_noise_updates)
        if not self.config.observation_noise or n == 0:
            return torch.zeros_like(self.pixel_noise_avg)
        return self.pixel_noise_avg / (1.0 - _NOISE_DECAY**n)  # bias-corrected, as Adam

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any) -> None:
        # checkpoints written before the noise estimate existed: load them without one
        for name in ("pixel_noise_avg", "pixel_noise_updates"):
            state_dict.setdefault(prefix + name, getattr(self, name).clone())
        super()._load_from_state_dict(state_dict, prefix, *args)

    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        if self.ema_unet is None:
            return
        # Warm-up (as diffusers' EMAModel): early averages do not drag in the random init.
        n = int(self.ema_updates)
        decay = min(self.config.ema_decay, (1 + n) / (10 + n))
        ema = list(self.ema_unet.parameters())
        torch._foreach_lerp_(ema, [p.detach() for p in self.unet.parameters()], 1.0 - decay)
        self.ema_updates += 1

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.unet.parameters(), lr=self.config.lr)

    # --- inference --------------------------------------------------------------------------
    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Sample chunk by chunk, all noise drawn from ``generator``: ``sample_batch_size``
        images at a time on the CPU, at least ``DEVICE_SAMPLE_BATCH`` on an accelerator (a
        64 x 64 chunk of 32 leaves a GPU mostly idle)."""
        if generator is None:
            generator = torch.Generator().manual_seed(self.config.seed)
        size = self.config.sample_batch_size
        if self.device.type != "cpu":
            size = max(size, DEVICE_SAMPLE_BATCH)
        chunks = [self._sample_chunk(part, generator) for part in depth.split(size)]
        return torch.cat(chunks) if chunks else depth.new_zeros((0, 3, *depth.shape[-2:]))

    @torch.no_grad()
    def _sample_chunk(self, depth: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        unet, condition = self.inference_unet, self.condition(depth.to(self.device))
        layout = torch.channels_last if self.config.channels_last else torch.contiguous_format
        if self.config.channels_last:  # in place, idempotent; later training stays correct
            unet.to(memory_format=layout)
            condition = condition.contiguous(memory_format=layout)

        def denoise(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            with self._autocast():
                return conditional_output(unet, x, condition, t.expand(len(x)))

        scheduler = make_sampler(self.config.sampler, self.noise_scheduler)
        shape = (len(depth), 3, *depth.shape[-2:])
        x = sample(denoise, shape, scheduler, self.config.steps, generator, self.device, layout)
        foreground = self.to_foreground(x)
        std = self.pixel_noise_std.to(foreground.device)
        if bool(std.any()):
            noise = torch.randn(foreground.shape, generator=generator).to(foreground.device)
            foreground = (foreground + noise * std[None, :, None, None]).clamp(0.0, 1.0)
        return foreground

    def sample_speed(self, n: int = 8, size: int | None = None, repeats: int = 1) -> float:
        """Images per second of ``translate_foreground`` with the configured sampler and steps.

        One untimed call first (oneDNN picks its kernels for these shapes), then the median
        of ``repeats`` timed calls. ``python -m tactile_bench bench`` is the full benchmark.
        """
        size = size or self.config.image_size
        depth = torch.zeros(n, 1, size, size)
        was_training = self.training
        self.eval()
        times = []
        try:
            for i in range(repeats + 1):
                start = time.perf_counter()
                self.translate_foreground(depth, torch.Generator().manual_seed(0))
                if i:
                    times.append(time.perf_counter() - start)
        finally:
            self.train(was_training)
        return n / statistics.median(times)

    # --- diffusers-style export -------------------------------------------------------------
    def save_pretrained(self, directory: str | Path) -> Path:
        """``unet/`` (inference weights), ``scheduler/`` and ``tactile_bench.json`` (our config)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.inference_unet.save_pretrained(directory / "unet")
        self.noise_scheduler.save_pretrained(directory / "scheduler")
        meta = {
            "translator": self.name,
            "format": CHECKPOINT_FORMAT,
            "config": self.config.model_dump(mode="json"),
            "pixel_noise_avg": self.pixel_noise_avg.tolist(),
            "pixel_noise_updates": int(self.pixel_noise_updates),
        }
        (directory / PRETRAINED_CONFIG).write_text(json.dumps(meta, indent=2) + "\n")
        return directory

    @classmethod
    def from_pretrained(cls, directory: str | Path) -> DiffusionTranslator:
        """Load a ``save_pretrained`` directory; a local path only, never a hub id."""
        directory = Path(directory)
        meta_path = directory / PRETRAINED_CONFIG
        if not meta_path.is_file():
            raise TactileBenchError(f"{directory}: no {PRETRAINED_CONFIG}; not a saved translator")
        meta = json.loads(meta_path.read_text())
        if meta.get("translator") != cls.name:
            raise TactileBenchError(
                f"{directory}: saved translator {meta.get('translator')!r}, not {cls.name!r}"
            )
        translator = cls(meta["config"])
        unet = UNet2DModel.from_pretrained(directory / "unet", local_files_only=True)
        translator.unet.load_state_dict(unet.state_dict())
        if translator.ema_unet is not None:
            translator.ema_unet.load_state_dict(unet.state_dict())
        translator.noise_scheduler = DDPMScheduler.from_pretrained(
            directory / "scheduler", local_files_only=True
        )
        translator.pixel_noise_avg.copy_(torch.tensor(meta.get("pixel_noise_avg", [0.0] * 3)))
        translator.pixel_noise_updates.fill_(int(meta.get("pixel_noise_updates", 0)))
        return translator
