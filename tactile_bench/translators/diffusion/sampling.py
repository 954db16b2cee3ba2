"""Noise schedules and the reverse process, kept apart from the network (the diffusers way).

Training always uses the paper's DDPM forward process (linear betas 1e-4 .. 0.02, T = 500).
Sampling can run that same 500-step ancestral DDPM chain, or one of diffusers' fast solvers
that reuse the trained model unchanged (DDIM, DPM-Solver++, UniPC). Samplers are a name ->
(class, overrides) table so a new one is one line, not a new branch. ``python -m tactile_bench
bench`` measures every one against DDPM-500 (docs/results/bench.md).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from functools import cache
from typing import Any

import torch
from diffusers import (
    DDIMScheduler,
    DDPMScheduler,
    DPMSolverMultistepScheduler,
    UniPCMultistepScheduler,
)
from diffusers.schedulers.scheduling_utils import SchedulerMixin

# name -> (scheduler class, settings on top of the training schedule's config)
SAMPLERS: dict[str, tuple[type[SchedulerMixin], dict[str, Any]]] = {
    "ddpm": (DDPMScheduler, {}),
    # "trailing" starts the short chain at t = T - 1, not T - T/steps (Lin et al. 2023).
    "ddim": (DDIMScheduler, {"timestep_spacing": "trailing", "set_alpha_to_one": True}),
    "dpmsolver++": (
        DPMSolverMultistepScheduler,
        {"algorithm_type": "dpmsolver++", "solver_order": 2, "timestep_spacing": "linspace"},
    ),
    # UniPC (Zhao et al. 2023): predictor-corrector, strong at very few steps.
    "unipc": (UniPCMultistepScheduler, {"solver_order": 2, "timestep_spacing": "trailing"}),
}

Denoiser = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

# What the network regresses, given (scheduler, x0, noise, t): the paper predicts the noise.
TARGETS: dict[str, Callable[..., torch.Tensor]] = {
    "epsilon": lambda scheduler, x0, noise, t: noise,
    "sample": lambda scheduler, x0, noise, t: x0,
    "v_prediction": lambda scheduler, x0, noise, t: scheduler.get_velocity(x0, noise, t),
}


def training_scheduler(
    train_timesteps: int = 500,
    beta_start: float = 1e-4,
    beta_end: float = 0.02,
    clip_range: float = 1.0,
    prediction_type: str = "epsilon",
) -> DDPMScheduler:
    """The paper's forward process; x0 predictions are clipped to the data's possible range."""
    return DDPMScheduler(
        num_train_timesteps=train_timesteps,
        beta_start=beta_start,
        beta_end=beta_end,
        beta_schedule="linear",
        prediction_type=prediction_type,
        clip_sample=True,
        clip_sample_range=clip_range,
    )


def make_sampler(name: str, train_scheduler: SchedulerMixin) -> SchedulerMixin:
    """A fresh (stateless) sampler of the given name sharing the training noise schedule."""
    try:
        cls, overrides = SAMPLERS[name]
    except KeyError:
        raise ValueError(f"unknown sampler {name!r} (known: {', '.join(SAMPLERS)})") from None
    return cls.from_config({**dict(train_scheduler.config), **overrides})


@cache
def _takes_generator(cls: type) -> bool:
    """Whether ``cls.step`` draws noise (and so takes a ``generator``): DDPM, DDIM do."""
    return "generator" in inspect.signature(cls.step).parameters


@torch.no_grad()
def sample(
    denoise: Denoiser,
    shape: tuple[int, ...],
    scheduler: SchedulerMixin,
    steps: int,
    generator: torch.Generator | None = None,
    device: torch.device | str = "cpu",
    memory_format: torch.memory_format = torch.contiguous_format,
) -> torch.Tensor:
    """Run the reverse process from pure Gaussian noise; every random draw uses ``generator``.

    ``denoise(x_t, t)`` returns the network output (of the scheduler's ``prediction_type``).
    ``memory_format`` is the layout of x_t (channels_last keeps the network's convolutions
    from converting layouts at every step).
    """
    scheduler.set_timesteps(steps, device=device)
    x = torch.randn(shape, generator=generator, dtype=torch.float32).to(device)
    x = (x * scheduler.init_noise_sigma).contiguous(memory_format=memory_format)
    extra = {"generator": generator} if _takes_generator(type(scheduler)) else {}
    for t in scheduler.timesteps:
        model_input = scheduler.scale_model_input(x, t)
        output = denoise(model_input, t).float()
        x = scheduler.step(output, t, x, **extra).prev_sample
    return x
