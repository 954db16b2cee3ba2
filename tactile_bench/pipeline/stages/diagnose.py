"""Stage ``diagnose``: the gap diagnosis on a data stage's pairs (sim vs "real").

It reads the set's depth, sim and real images only, as the command ``diagnose`` reads a
paired folder: never the profile of the sensor that played "real". On a ``paired_data``
stage it keeps that folder's labels, gel view and whether it had its own sim no-contact
frame; its ``all`` set, at ``fit_fraction`` = 1 - holdout, is split as that stage split it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from pydantic import Field

from tactile_bench.classify.train import ClassifierConfig, classifier_precision
from tactile_bench.data.braille import BrailleSet
from tactile_bench.diagnose.paired import DiagnosisPairs, braille_stage_chars, from_braille_set
from tactile_bench.diagnose.run import check_candidates, diagnose, stratified_split
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind, StageResult
from tactile_bench.pipeline.stages.braille_data import SETS
from tactile_bench.pipeline.stages.paired_data import SET_FILES


class DiagnoseConfig(StageConfig):
    """Which set to diagnose, which candidate effects, and whether to run the classifier part."""

    set: str = Field(
        default="test",
        description="set of the data stage to diagnose (a paired_data stage also has all)",
    )
    downstream: bool = Field(
        default=True, description="also train classifiers on sim + the effects found"
    )
    candidates: list[str] | None = Field(
        default=None, description="candidate effects; None: all (see `list effects`)"
    )
    fit_fraction: float = Field(
        default=0.5, gt=0.0, lt=1.0, description="share of the pairs to fit on; the rest test"
    )
    max_pairs: int | None = Field(
        default=None, ge=4, description="a stratified subset of this many pairs; None: all"
    )


def _check(config: DiagnoseConfig, base_dir: Path) -> None:
    known = list(dict.fromkeys([*SETS, *SET_FILES]))
    if config.set not in known:
        raise TactileBenchError(f"set: {config.set!r} is not one of {', '.join(known)}")
    check_candidates(config.candidates, "candidates")


def stage_pairs(data_stage: StageResult, name: str, stage: str) -> DiagnosisPairs:
    """The data stage's set ``name`` as paired data: its labels (a paired_data stage's own
    names, else braille characters), its gel view and sim frame as that stage records."""
    if name not in data_stage.outputs:
        raise TactileBenchError(
            f"stage {stage}: set: data stage {data_stage.name!r} ({data_stage.kind}) has no "
            f"{name!r} set; it has {', '.join(sorted(data_stage.outputs))}"
        )
    metrics = data_stage.metrics
    chars = metrics.get("classes") or braille_stage_chars(data_stage.directory) or CHARACTERS
    data = from_braille_set(BrailleSet.load(data_stage.path(name)), chars)
    if "gel_mm" in metrics:
        data = dataclasses.replace(data, gel_mm=tuple(metrics["gel_mm"]))
    if metrics.get("sim_background_given") is False:  # the real frame stood in for it
        data = dataclasses.replace(data, sim_background=None)
    return data


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: DiagnoseConfig = ctx.config
    data_stage = ctx.input("data")
    data = stage_pairs(data_stage, config.set, ctx.name)
    if config.max_pairs is not None and len(data) > config.max_pairs:
        keep, _ = stratified_split(data.labels, config.max_pairs / len(data), ctx.seed)
        data = data.subset(keep)
    result = diagnose(
        data,
        ctx.directory,
        downstream=config.downstream,
        candidates=config.candidates,
        seed=ctx.seed,
        fit_fraction=config.fit_fraction,
        progress=ctx.progress,
        source={"root": str(data_stage.directory), "layout": data_stage.kind, "set": config.set},
    )
    top = result.which.ranking[0] if result.which.ranking else None
    metrics = {
        "n_pairs": result.n_pairs,
        "mse": result.where.summary["mse"],
        "top_effect": top.effect if top else None,
        "top_shrink": top.shrink if top else None,
        "unexplained": result.which.unexplained,
        # the precision its downstream classifiers (default config) trained in; None: none
        "compute_precision": (
            classifier_precision(ClassifierConfig()) if config.downstream else None
        ),
    }
    return {"report_json": "report.json", "report_html": "report.html"}, metrics


STAGE = StageKind(
    name="diagnose",
    description="gap diagnosis of a braille set: where the gap lies, which effect, how far",
    config_model=DiagnoseConfig,
    run=_run,
    input_slots={"data": True},
    check=_check,
    precision_dependent=True,
)
