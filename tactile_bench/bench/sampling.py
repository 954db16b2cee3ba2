"""Diffusion sampling: images/s and quality of each sampler and step count, against DDPM-500.

Every row samples the SAME trained network on the SAME braille test contacts, in the same
chunks of ``sample_batch_size``, with the same seed; only the sampler and its number of
steps change. The paper's sampler (ancestral DDPM over all 500 training timesteps) is the
baseline row, and every speed is also given as a ratio to it, measured in the same run.

Quality is measured two ways against the real images of the same contacts:
- SSIM (and MSE) on 0..255, as the paper reports them;
- ``texture``: mean |Laplacian| of the generated images over that of the real ones. SSIM
  rewards a smooth conditional mean as much as a sample; ``texture`` near 1 says the
  sampler also reproduces the sensor's fine structure and noise, below 1 that it smooths
  them away (so a fast sampler is not judged on SSIM alone).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from tactile_bench.bench.timing import measure
from tactile_bench.data.braille import BrailleSet
from tactile_bench.hardware import native_bf16, resolve_precision
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.translators.diffusion import PRESETS, DiffusionTranslator, build_unet
from tactile_bench.translators.diffusion.torch_model import conditional_output

BASELINE_SAMPLER = "ddpm"  # the paper's: ancestral DDPM over every training timestep (500)


@dataclass(frozen=True)
class Case:
    """One row of the table: a sampler name (see ``SAMPLERS``) and its number of steps."""

    sampler: str
    steps: int


def texture(images: torch.Tensor) -> float:
    """Mean absolute 4-neighbour Laplacian of (N, 3, S, S) images in 0..255."""
    kernel = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]])
    kernel = kernel.view(1, 1, 3, 3).repeat(images.shape[1], 1, 1, 1)
    return float(F.conv2d(images.float(), kernel, groups=images.shape[1]).abs().mean())


def _with(translator: DiffusionTranslator, **settings: Any) -> DiffusionTranslator:
    """The same weights with other inference settings (a shallow copy shares the network)."""
    clone = copy.copy(translator)
    clone.config = translator.parse_config(translator.config.model_dump() | settings)
    return clone


def run_case(
    translator: DiffusionTranslator,
    data: BrailleSet,
    case: Case,
    repeats: int,
    seed: int = 0,
) -> dict[str, Any]:
    """Time ``translate`` of all of ``data`` with one sampler; score the images against real.

    The warm-up is one step of the same sampler on the same chunks, so oneDNN has chosen
    its kernels for these shapes before the clock starts, without paying a whole chain.
    """
    model = _with(translator, sampler=case.sampler, steps=case.steps)
    background = data.real_background.float()
    _with(model, steps=1).translate(data.depth, background, torch.Generator().manual_seed(seed))
    out: dict[str, torch.Tensor] = {}

    def run() -> None:
        out["images"] = model.translate(data.depth, background, torch.Generator().manual_seed(seed))

    timing = measure(run, len(data), repeats=repeats, warmup=0)
    images = out["images"].round().clamp(0, 255)
    similarity = ssim_mse(images, data.real.float())
    return {
        "sampler": case.sampler,
        "steps": case.steps,
        "images": len(data),
        "images_per_s": timing.per_s,
        "images_per_cpu_s": timing.per_cpu_s,
        "evals_per_s": timing.per_s * case.steps,
        "ssim": similarity["ssim"],
        "mse": similarity["mse"],
        "texture": texture(images) / max(texture(data.real), 1e-9),
        "timing": timing.to_dict(),
    }


def sampling_table(
    translator: DiffusionTranslator,
    test: BrailleSet,
    cases: Sequence[Case],
    n_images: int,
    repeats: int,
    n_default: int,
    baseline_repeats: int = 1,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """DDPM-500 and every case on the same ``n_images`` test contacts; the default on more.

    The baseline is DDPM over all ``train_timesteps`` of the model (500 for the paper's
    schedule and ours; tests use shorter schedules). Ratios (``speedup_vs_ddpm500``) divide
    each row's images/s by the baseline row's, both measured here. The default sampler runs
    again on ``n_default`` contacts (the whole test set in a full run) for an SSIM on the
    full set and a steadier speed.
    """
    idx = torch.randperm(len(test), generator=torch.Generator().manual_seed(seed))
    subset = test.subset(idx[: min(n_images, len(test))])
    large = test.subset(idx[: min(n_default, len(test))])

    def say(row: dict[str, Any]) -> None:
        if progress:
            print(
                f"  sampling {row['sampler']:>12}-{row['steps']:<4d} {row['images']:5d} img  "
                f"{row['images_per_s']:8.3f} img/s  SSIM {row['ssim']:.4f}  "
                f"texture {row['texture']:.2f}",
                flush=True,
            )

    default_case = Case(translator.config.sampler, translator.config.steps)
    if default_case not in cases:
        cases = [*cases, default_case]
    baseline_case = Case(BASELINE_SAMPLER, translator.config.train_timesteps)
    baseline = run_case(translator, subset, baseline_case, baseline_repeats, seed)
    say(baseline)
    rows = [baseline]
    for case in cases:
        if case == baseline_case or case.steps > baseline_case.steps:
            continue
        rows.append(run_case(translator, subset, case, repeats, seed))
        say(rows[-1])
    full = run_case(translator, large, default_case, repeats, seed)
    say(full)
    for row in rows:
        row["subset"] = "ddpm500"
    full["subset"] = "large"
    for row in [*rows, full]:
        row["speedup_vs_ddpm500"] = row["images_per_s"] / baseline["images_per_s"]
        row["cpu_speedup_vs_ddpm500"] = row["images_per_cpu_s"] / baseline["images_per_cpu_s"]
        row["ssim_minus_ddpm500"] = row["ssim"] - baseline["ssim"]
        row["default"] = (row["sampler"], row["steps"]) == (
            default_case.sampler,
            default_case.steps,
        )
    return {
        "rows": rows,
        "default_large": full,
        "baseline": {"sampler": baseline_case.sampler, "steps": baseline_case.steps},
        "test_images": len(subset),
        "sample_batch_size": translator.config.sample_batch_size,
        "precision": translator.config.precision,
        "compute_precision": translator.inference_precision(),
        "channels_last": getattr(translator.config, "channels_last", False),
    }


def preset_speed(
    presets: Sequence[str], batch: int, image_size: int, repeats: int, precision: str = "auto"
) -> dict[str, Any]:
    """Network evaluations per second of each UNet preset (random weights: speed only).

    One evaluation is one denoising step for one image, so DDPM-500 images/s is this
    divided by 500 and an N-step solver's is this divided by N. ``precision`` as in a
    config: ``auto`` measures what sampling uses on this machine.
    """
    compute = resolve_precision(precision)
    bf16 = compute == "bf16-mixed"
    layout = torch.channels_last
    x = torch.randn(batch, 3, image_size, image_size).contiguous(memory_format=layout)
    c = torch.rand(batch, 1, image_size, image_size).contiguous(memory_format=layout)
    t = torch.full((batch,), 250)
    out = {}
    for name in presets:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            unet = build_unet(PRESETS[name], image_size).eval().to(memory_format=layout)

        def run(unet: torch.nn.Module = unet) -> None:
            with torch.no_grad(), torch.autocast("cpu", torch.bfloat16, enabled=bf16):
                conditional_output(unet, x, c, t)

        timing = measure(run, batch, repeats=repeats, warmup=1)
        params = sum(p.numel() for p in unet.parameters())
        out[name] = {
            "params": params,
            "compute_precision": compute,
            "evals_per_s": timing.per_s,
            "ddpm500_images_per_s": timing.per_s / 500,
            "timing": timing.to_dict(),
        }
    return out


#: images of the bf16 row on a CPU that emulates bf16 (its rate, not its quality, matters)
EMULATED_BF16_IMAGES = 8

# name -> settings on top of the translator's own; the first row is the shipped default
INFERENCE_VARIANTS: dict[str, dict[str, Any]] = {
    "as configured": {},
    "fp32": {"precision": "32-true"},
    "bf16": {"precision": "bf16-mixed"},
    "NCHW (no channels_last)": {"channels_last": False},
    "fp32, NCHW": {"precision": "32-true", "channels_last": False},
    "batch 128": {"sample_batch_size": 128},
}


def inference_variants(
    translator: DiffusionTranslator, data: BrailleSet, repeats: int, seed: int = 0
) -> list[dict[str, Any]]:
    """Where the default sampler's speed comes from: each inference setting switched off.

    Every row runs the default sampler and steps on the same contacts; ``vs_default`` is
    its images/s over the default row's, measured in this run. Converting the network back
    to NCHW for the NCHW rows is part of the measurement set-up, not of the timed work.
    """
    rows = []
    case = Case(translator.config.sampler, translator.config.steps)
    for name, settings in INFERENCE_VARIANTS.items():
        model = _with(translator, **settings)
        if not model.config.channels_last:
            model.inference_unet.to(memory_format=torch.contiguous_format)
        subset, times = data, repeats
        if model.inference_precision() == "bf16-mixed" and not native_bf16():
            # emulated bf16 runs 20-100x slower: a few images, timed once, tell the rate
            subset, times = data.subset(slice(0, EMULATED_BF16_IMAGES)), 1
        row = run_case(model, subset, case, times, seed)
        cfg = model.config
        layout = {
            "precision": cfg.precision,
            "compute_precision": model.inference_precision(),
            "channels_last": cfg.channels_last,
        }
        rows.append({"variant": name, **layout, "batch": cfg.sample_batch_size, **row})
    if translator.config.channels_last:
        translator.inference_unet.to(memory_format=torch.channels_last)
    base = rows[0]["images_per_s"]
    for row in rows:
        row["vs_default"] = row["images_per_s"] / base
    return rows
