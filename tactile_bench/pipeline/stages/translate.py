"""Stage ``translate``: turn braille depth into images with a translator, and score the test set.

The translator is either a fitted one (input ``translator``, a ``fit_translator`` stage)
or a fresh registered one named in the config (``sim``; ``lighting_aug`` unfitted, with the
sim's noise).
``translator_config`` on a fitted translator overrides inference settings only (e.g. the
diffusion sampler and its number of steps).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import torch
from pydantic import Field
from tqdm.auto import tqdm

from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.pixels import to_uint8
from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import compute_device
from tactile_bench.io import atomic_write_json, atomic_write_npz
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.pipeline.stages.fit_translator import load_fitted, recipe_translator_config
from tactile_bench.translators import create_translator, translator_class

#: contacts translated at a time, at least, on an accelerator (a GPU idles on a few hundred)
DEVICE_CHUNK = 4096


class TranslateConfig(StageConfig):
    """Which translator (when none is fitted upstream), which sets, onto which background."""

    translator: str | None = Field(
        default=None,
        description="translator to build when no fit stage is connected (e.g. sim); None: the "
        "fitted one",
    )
    translator_config: dict[str, Any] = Field(
        default={}, description="its config, for a translator built here"
    )
    sets: list[Literal["finetune", "test", "classifier"]] = Field(
        default=["classifier", "test"], description="braille sets to translate"
    )
    background: Literal["sim", "real"] = Field(
        default="real", description="no-contact frame the images are composed on"
    )
    batch_size: int = Field(default=256, ge=1, description="contacts translated at a time")


def _check(config: TranslateConfig, base_dir: Path) -> None:
    if config.translator is None:
        return
    try:
        translator_class(config.translator).parse_config(
            recipe_translator_config(config.translator, config.translator_config, base_dir)
        )
    except TactileBenchError as exc:
        raise TactileBenchError(f"translator: {exc}") from None


def _translator(ctx: StageContext) -> Any:
    config: TranslateConfig = ctx.config
    fitted = load_fitted(ctx, "translator")
    if fitted is None:
        if config.translator is None:
            raise TactileBenchError(f"stage {ctx.name}: name a translator or connect a fitted one")
        settings = recipe_translator_config(
            config.translator, config.translator_config, ctx.recipe_dir
        )
        return create_translator(config.translator, settings)
    if config.translator not in (None, fitted.name):
        raise TactileBenchError(
            f"stage {ctx.name}: config names {config.translator!r} but the fitted translator "
            f"is {fitted.name!r}"
        )
    if config.translator_config:
        settings = fitted.config.model_dump() | recipe_translator_config(
            fitted.name, config.translator_config, ctx.recipe_dir
        )
        fitted.config = fitted.parse_config(settings)
    return fitted


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: TranslateConfig = ctx.config
    data = ctx.input("data")
    missing = [name for name in config.sets if name not in data.outputs]
    if missing:
        raise TactileBenchError(
            f"stage {ctx.name}: sets: data stage {data.name!r} ({data.kind}) has no "
            f"{', '.join(missing)} set; list only sets it has"
        )
    device = compute_device(ctx.trainer.get("accelerator"))
    translator = _translator(ctx).to(device)
    generator = torch.Generator().manual_seed(ctx.seed)
    chunk = config.batch_size if device.type == "cpu" else max(config.batch_size, DEVICE_CHUNK)
    outputs: dict[str, str] = {}
    metrics: dict[str, Any] = {
        "translator": translator.name,
        "compute_precision": translator.inference_precision(),
    }
    for name in config.sets:
        split = BrailleSet.load(data.path(name))
        background = (
            split.sim_background if config.background == "sim" else split.real_background
        ).float()
        background_there = background.to(device)
        chunks = []
        with tqdm(
            total=len(split),
            desc=f"translate {name} ({translator.name})",
            unit="image",
            disable=not ctx.progress,
        ) as bar:
            for i in range(0, len(split), chunk):
                depth = split.depth[i : i + chunk].to(device)
                # stored as uint8 chunk by chunk: a float copy of a 10k-image set is 0.5 GB
                image = translator.translate(depth, background_there, generator)
                chunks.append(to_uint8(image).cpu())
                bar.update(len(depth))
        images = torch.cat(chunks)
        atomic_write_npz(
            ctx.directory / f"{name}.npz",
            images=images.numpy(),
            background=background.round().to(torch.uint8).numpy(),
            labels=split.labels.numpy(),
        )
        outputs[name] = f"{name}.npz"
        if name == "test":
            metrics["test_similarity"] = ssim_mse(images.float(), split.real.float())
    atomic_write_json(ctx.directory / "metrics.json", metrics)
    outputs["metrics"] = "metrics.json"
    return outputs, metrics


STAGE = StageKind(
    name="translate",
    description="translate braille depth into images; SSIM/MSE against real on the test set",
    config_model=TranslateConfig,
    run=_run,
    input_slots={"data": True, "translator": False},
    check=_check,
    precision_dependent=True,
)
