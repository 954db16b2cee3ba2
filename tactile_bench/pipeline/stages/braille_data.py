"""Stage ``braille_data``: the paper's braille contacts as (depth, sim, real) sets.

``source: surrogate`` (default) simulates every set with the surrogate DIGIT as the real
sensor; ``source: PATH`` reads the real sets from a folder in the Tactile-Diffusion layout
(see ``data.braille_layout``) and simulates only the classifier grid, as the paper did.
The stage's metrics say which sets carry real and sim images (``content``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from pydantic import Field

from tactile_bench.data.braille import build_braille_sets
from tactile_bench.data.braille_layout import LAYOUT_CONTENT, check_braille_layout, load_layout_sets
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    check_real_sensor,
    real_sensor,
    resolve_source,
)
from tactile_bench.report.figures import sample_grid_png
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.optics import SimOptics

SETS = ("finetune", "test", "classifier", "classifier_test")


class BrailleDataConfig(StageConfig):
    """Which characters, how many fine-tuning/test contacts, and which sensor plays "real"
    (``source: surrogate``), or a folder of real data in the Tactile-Diffusion layout."""

    source: str = "surrogate"
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
    check_real_sensor(config.real_sensor, base_dir)
    if config.source != "surrogate":
        check_braille_layout(resolve_source(config.source, base_dir))


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: BrailleDataConfig = ctx.config
    chars = tuple(config.chars)
    gel = GelSpec(size=config.image_size, oversample=config.oversample)
    bank = build_bank(chars, BrailleSpec())
    simulated = config.source == "surrogate"
    real = real_sensor(config.real_sensor, ctx.recipe_dir)
    sets = build_braille_sets(
        bank,
        gel,
        SimOptics(),
        sim_background(config.image_size),
        real,
        seed=ctx.seed,
        chars=chars,
        # with a real-data source only the classifier grid is used: keep the others minimal
        n_finetune=config.n_finetune if simulated else len(chars),
        n_test=config.n_test if simulated else len(chars),
        n_classifier=config.n_classifier,
        n_classifier_test=config.n_classifier_test if simulated else len(chars),
        progress=ctx.progress,
    )
    content = {name: {"has_sim": True, "has_real": True} for name in SETS}
    if not simulated:
        root = resolve_source(config.source, ctx.recipe_dir)
        sets = load_layout_sets(
            root, gel, sim_background(config.image_size), sets["classifier"], ctx.seed, chars
        )
        content = LAYOUT_CONTENT
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
    real = config.real_sensor if config.source == "surrogate" else config.source
    return outputs, {"real_sensor": real, "content": content} | {n: len(sets[n]) for n in SETS}


STAGE = StageKind(
    name="braille_data",
    description="simulate braille contacts: fine-tuning pool, test set, classifier set",
    config_model=BrailleDataConfig,
    run=_run,
    check=_check,
)
