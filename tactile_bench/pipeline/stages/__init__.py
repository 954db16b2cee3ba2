"""The registry of stage kinds a recipe may name; listed explicitly, no import magic."""

from tactile_bench.pipeline.stages import (
    braille_data,
    calibrate,
    classify,
    compare_translators,
    diagnose,
    effect_ablation,
    fit_translator,
    paired_data,
    report,
    sensor_report,
    translate,
    ycb_slide_data,
)
from tactile_bench.pipeline.stages.base import StageContext, StageKind, StageResult

STAGES: dict[str, StageKind] = {
    stage.name: stage
    for stage in (
        braille_data.STAGE,
        ycb_slide_data.STAGE,
        paired_data.STAGE,
        calibrate.STAGE,
        fit_translator.STAGE,
        translate.STAGE,
        classify.STAGE,
        compare_translators.STAGE,
        effect_ablation.STAGE,
        report.STAGE,
        sensor_report.STAGE,
        diagnose.STAGE,
    )
}

__all__ = ["STAGES", "StageContext", "StageKind", "StageResult"]
