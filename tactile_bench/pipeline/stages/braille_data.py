"""Stage ``braille_data``: the paper's braille contacts as (depth, sim, real) sets.

``source: surrogate`` (default) simulates every set with the surrogate DIGIT as the real
sensor; ``source: PATH`` reads the real sets from a folder in the Tactile-Diffusion layout
(the ``braille`` folder or its parent ``datasets``; see ``data.braille_layout``) and
simulates only the classifier grid, as the paper did. Without the release's split file the
stage draws one as ``train_braille.py`` does, from the recipe's seed, and writes it here
(``files_train_test.npy``), never into the dataset. ``sim_source: release`` adds the
release's TACTO frames (``sim_release``) for the paper's Sim row.
The stage's metrics say which sets carry real and sim images (``content``).
``second_unit: PROFILE`` renders the classifier test contacts again with another surrogate
unit as "real" (``classifier_test_second_unit``): the classify stages score every model on
it, and nothing else reads it, so no translator or classifier sees that unit before.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field, SerializerFunctionWrapHandler, model_serializer

from tactile_bench.data.braille import build_braille_sets
from tactile_bench.data.braille_layout import (
    LAYOUT_CONTENT,
    SIM_RELEASE_CONTENT,
    check_braille_layout,
    load_layout_sets,
)
from tactile_bench.data.tactile_diffusion import (
    DATASET_RATIO,
    SPLIT_FILE,
    TEST_RATIO,
    braille_root,
    split_for_run,
)
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

#: the sets every braille_data stage writes (``second_unit`` adds classifier_test_second_unit)
SETS = ("finetune", "test", "classifier", "classifier_test")
#: real source: which finetune pairs the translator split tests on (fit_translator skips them)
HELD_OUT_FILE = "finetune_in_test.npy"


class BrailleDataConfig(StageConfig):
    """Which characters, how many fine-tuning/test contacts, and which sensor plays "real"
    (``source: surrogate``), or a folder of real data in the Tactile-Diffusion layout."""

    source: str = Field(
        default="surrogate",
        description="surrogate: render every set with real_sensor playing 'real'; or a folder "
        "of real data in the Tactile-Diffusion layout (docs/real_data.md)",
    )
    chars: str = Field(
        default="".join(CHARACTERS), min_length=2, description="braille characters, one a class"
    )
    n_finetune: int = Field(
        default=1080, ge=1, description="contacts of the paired fine-tuning pool (yaw to 90 deg)"
    )
    n_test: int = Field(
        default=837, ge=1, description="contacts of the paired test set the translators' SSIM uses"
    )
    n_classifier: int | None = Field(
        default=None,
        ge=1,
        description="classifier training contacts, a stratified draw; None: the whole grid",
    )
    n_classifier_test: int = Field(
        default=837, ge=1, description="upright, off-grid contacts the classifiers are tested on"
    )
    real_sensor: str = Field(
        default="digit", description="surrogate profile playing 'real': a name or a YAML path"
    )
    second_unit: str | None = Field(
        default=None,
        description="surrogate profile (a name or a YAML path) of a second unit that renders "
        "the classifier_test contacts again, used for nothing but testing every classifier "
        "(the table's second-unit column); None: no such set",
    )
    image_size: int = Field(default=64, ge=16, le=256, description="image side in pixels")
    oversample: int = Field(
        default=2, ge=1, le=8, description="depth rendered at this many times the image size"
    )
    sim_source: Literal["simulate", "release"] = Field(
        default="simulate",
        description="release: also read sim_tacto/color (the paper's Sim row images)",
    )
    split_ratio: float = Field(
        default=DATASET_RATIO, gt=0.0, le=1.0, description="dataset_ratio of a drawn split"
    )
    split_test_ratio: float = Field(
        default=TEST_RATIO, gt=0.0, lt=1.0, description="test_ratio of a drawn split"
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Unset, ``second_unit`` is left out of the dump (the cache key): the stages of
        recipes without it keep their keys and stay cached."""
        data = handler(self)
        if self.second_unit is None:
            data.pop("second_unit", None)
        return data


def source_root(config: BrailleDataConfig, base_dir: Path) -> Path:
    """The braille folder ``source:`` names (itself or its ``braille/`` child)."""
    path = resolve_source(config.source, base_dir)
    try:
        return braille_root(path)
    except TactileBenchError:
        raise TactileBenchError(
            f"source: {path}: folder not found or not the Tactile-Diffusion braille layout "
            "(expected real_fine_tuning/{color,mask}, real/color, bgs in it or in its braille/)"
        ) from None


def _check(config: BrailleDataConfig, base_dir: Path) -> None:
    unknown = sorted(set(config.chars) - set(CHARACTERS))
    if unknown:
        raise TactileBenchError(f"chars: not braille characters of the paper: {''.join(unknown)}")
    check_real_sensor(config.real_sensor, base_dir)
    if config.second_unit is not None:
        if config.source != "surrogate":
            raise TactileBenchError(
                "second_unit: needs source: surrogate (a real-data source's classifier_test "
                "frames have no poses another unit could render)"
            )
        try:
            real_sensor(config.second_unit, base_dir)
        except TactileBenchError as exc:
            raise TactileBenchError(f"second_unit: {exc}") from None
    if config.source == "surrogate":
        if config.sim_source == "release":
            raise TactileBenchError(
                "sim_source: release needs a real-data source (the release's sim_tacto/color)"
            )
        return
    check_braille_layout(source_root(config, base_dir), config.sim_source == "release")


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: BrailleDataConfig = ctx.config
    chars = tuple(config.chars)
    gel = GelSpec(size=config.image_size, oversample=config.oversample)
    bank = build_bank(chars, BrailleSpec())
    simulated = config.source == "surrogate"
    real = real_sensor(config.real_sensor, ctx.recipe_dir)
    second_unit = (
        None if config.second_unit is None else real_sensor(config.second_unit, ctx.recipe_dir)
    )
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
        second_unit=second_unit,
    )
    content: dict[str, Any] = {name: {"has_sim": True, "has_real": True} for name in sets}
    outputs = {}
    extra: dict[str, Any] = {}
    if not simulated:
        root = source_root(config, ctx.recipe_dir)
        split, origin = split_for_run(
            root,
            ctx.seed,
            write_to=ctx.directory / SPLIT_FILE,
            dataset_ratio=config.split_ratio,
            test_ratio=config.split_test_ratio,
        )
        if (ctx.directory / SPLIT_FILE).exists():
            outputs["split"] = SPLIT_FILE
        release = config.sim_source == "release"
        sets, in_test = load_layout_sets(
            root,
            gel,
            sim_background(config.image_size),
            sets["classifier"],
            ctx.seed,
            chars,
            split,
            sim_release=release,
        )
        np.save(ctx.directory / HELD_OUT_FILE, in_test)
        outputs["finetune_in_test"] = HELD_OUT_FILE
        content = dict(LAYOUT_CONTENT) | ({"sim_release": SIM_RELEASE_CONTENT} if release else {})
        extra = {"source_root": str(root), "split": origin}
    for name in sets:
        sets[name].save(ctx.directory / f"{name}.npz")
        outputs[name] = f"{name}.npz"

    test = sets["test"]
    picks = [
        int(torch.nonzero(test.labels == i)[0])
        for i in range(min(6, len(chars)))
        if bool((test.labels == i).any())
    ]
    real_name = "surrogate real" if simulated else "real"
    sample_grid_png(
        {"depth": test.depth[picks], "sim": test.sim[picks], real_name: test.real[picks]},
        [chars[int(test.labels[i])] for i in picks],
        ctx.directory / "preview.png",
        title=f"braille contacts: depth | sim | {real_name}",
    )
    outputs["preview"] = "preview.png"
    real = config.real_sensor if config.source == "surrogate" else config.source
    counts = {n: len(sets[n]) for n in sets}
    if second_unit is not None:  # the profile's name, as the table's column names the unit
        extra["second_unit"] = second_unit.name
    return outputs, {"real_sensor": real, "content": content} | extra | counts


STAGE = StageKind(
    name="braille_data",
    description="simulate braille contacts: fine-tuning pool, test set, classifier set",
    config_model=BrailleDataConfig,
    run=_run,
    check=_check,
)
