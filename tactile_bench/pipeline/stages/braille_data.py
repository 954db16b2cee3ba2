"""Stage ``braille_data``: simulate the paper's braille contacts as (depth, sim, real) sets."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from pydantic import Field

from tactile_bench.data.braille import build_braille_sets
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    check_real_sensor,
)
from tactile_bench.report.figures import sample_grid_png
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit

SETS = ("finetune", "test", "classifier", "classifier_test")


class BrailleDataConfig(StageConfig):
    """Which characters, how many fine-tuning/test contacts, and which sensor plays "real"."""

    chars: str = Field(default="".join(CHARACTERS), min_length=2)
    n_finetune: int = Field(default=1080, ge=1)
    n_test: int = Field(default=837, ge=1)
    n_classifier: int | None = Field(default=None, ge=1, description="None: the whole grid")
    n_classifier_test: int = Field(default=837, ge=1)
    real_sensor: str = "digit"
    image_size: int = Field(default=64, ge=16, le=256)
    oversample: int = Field(default=2, ge=1, le=8)


def _check(config: BrailleDataConfig, base_dir: Path) -> None:
    unknown = sorted(set(config.chars) - set(CHARACTERS))
    if unknown:
        raise TactileBenchError(f"chars: not braille characters of the paper: {''.join(unknown)}")
    check_real_sensor(config.real_sensor)


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: BrailleDataConfig = ctx.config
    chars = tuple(config.chars)
    gel = GelSpec(size=config.image_size, oversample=config.oversample)
    bank = build_bank(chars, BrailleSpec())
    real = SurrogateDigit.from_profile(config.real_sensor)
    sets = build_braille_sets(
        bank,
        gel,
        SimOptics(),
        sim_background(config.image_size),
        real,
        seed=ctx.seed,
        chars=chars,
        n_finetune=config.n_finetune,
        n_test=config.n_test,
        n_classifier=config.n_classifier,
        n_classifier_test=config.n_classifier_test,
        progress=ctx.progress,
    )
    outputs = {}
    for name in SETS:
        sets[name].save(ctx.directory / f"{name}.npz")
        outputs[name] = f"{name}.npz"

    test = sets["test"]
    picks = [
        int(torch.nonzero(test.labels == i)[0])
        for i in range(min(6, len(chars)))
        if bool((test.labels == i).any())
    ]
    sample_grid_png(
        {"depth": test.depth[picks], "sim": test.sim[picks], "surrogate real": test.real[picks]},
        [chars[int(test.labels[i])] for i in picks],
        ctx.directory / "preview.png",
        title="braille contacts: depth | sim | surrogate real",
    )
    outputs["preview"] = "preview.png"
    return outputs, {"real_sensor": config.real_sensor, **{name: len(sets[name]) for name in SETS}}


STAGE = StageKind(
    name="braille_data",
    description="simulate braille contacts: fine-tuning pool, test set, classifier set",
    config_model=BrailleDataConfig,
    run=_run,
    check=_check,
)
