"""Stage ``calibrate``: a sensor profile fitted to a ``paired_data`` stage's fit share.

The command ``calibrate`` on the stage's pairs, split as the stage split them (the same
``stratified_split``, seed and held-out share), so the profile never sees the held-out pairs
the translators are compared on. The stage also writes the profile as a ``profile``
translator (``translator.pt``, ``metrics.translator``), so a ``translate`` stage renders the
held-out depths with it and ``compare_translators`` puts the profile beside the learned
translators. That translator reads ``calibration/profile.yaml`` from this stage's folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import Field

from tactile_bench.calibrate.run import CURVE_FILE, JSON_FILE, MD_FILE, PROFILE_FILE
from tactile_bench.diagnose.run import check_candidates
from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.pipeline.stages.diagnose import stage_pairs
from tactile_bench.translators import create_translator

FOLDER = "calibration"


class CalibrateConfig(StageConfig):
    """Which effects the selection may search, and whether to draw the press-count curve."""

    curve: bool = Field(
        default=False,
        description="also calibrate on 4, 8, 16, ... of the fit pairs and plot held-out "
        "contact MSE against the number of presses",
    )
    candidates: list[str] | None = Field(
        default=None, description="candidate effects; None: every diagnosis candidate"
    )


def _check(config: CalibrateConfig, base_dir: Path) -> None:
    check_candidates(config.candidates, "candidates")


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    from tactile_bench.calibrate.run import calibrate_pairs

    config: CalibrateConfig = ctx.config
    data_stage = ctx.input("data")
    if "holdout" not in data_stage.metrics:
        raise TactileBenchError(
            f"stage {ctx.name}: data: {data_stage.name!r} is a {data_stage.kind} stage; "
            "calibrate reads a paired_data stage (a folder of your sensor's pairs)"
        )
    data = stage_pairs(data_stage, "all", ctx.name)
    folder = ctx.directory / FOLDER
    result = calibrate_pairs(
        data,
        folder,
        holdout=float(data_stage.metrics["holdout"]),
        seed=ctx.seed,
        curve=config.curve,
        progress=ctx.progress,
        overwrite=True,  # a rerun after a kill replaces what an earlier try left
        candidates=config.candidates,
        source=str(data_stage.metrics.get("source_root", data_stage.directory)),
    )
    if result["n_fit"] != data_stage.metrics["n_fit"]:  # the split is the data stage's
        raise TactileBenchError(
            f"stage {ctx.name}: fitted {result['n_fit']} pairs, but {data_stage.name!r} "
            f"holds {data_stage.metrics['n_fit']} in its fit share"
        )
    translator = create_translator(
        "profile",
        {"profile": str((folder / PROFILE_FILE).resolve()), "gel_mm": tuple(data.gel_mm)},
    )
    translator.save(ctx.directory / "translator.pt")
    outputs = {
        "profile": f"{FOLDER}/{PROFILE_FILE}",
        "calibration_json": f"{FOLDER}/{JSON_FILE}",
        "calibration_md": f"{FOLDER}/{MD_FILE}",
        "translator": "translator.pt",
    }
    if config.curve:
        outputs["curve"] = f"{FOLDER}/{CURVE_FILE}"
    metrics = {
        "translator": "profile",
        "n_fit": result["n_fit"],
        "n_heldout": result["n_heldout"],
        "selected": list(result["selected"]),
        "heldout": result["heldout"],
    }
    return outputs, metrics


STAGE = StageKind(
    name="calibrate",
    description="a sensor profile fitted to a paired_data stage's fit share, scored on its "
    "held-out share; also a profile translator for translate / compare_translators",
    config_model=CalibrateConfig,
    run=_run,
    input_slots={"data": True},
    check=_check,
    publish=("calibration_md",),
)
