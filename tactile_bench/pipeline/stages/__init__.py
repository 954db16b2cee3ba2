"""The registry of stage kinds a recipe may name; listed explicitly, no import magic."""

from tactile_bench.pipeline.stages import braille_data, classify, report, translate
from tactile_bench.pipeline.stages.base import StageContext, StageKind, StageResult

STAGES: dict[str, StageKind] = {
    stage.name: stage
    for stage in (braille_data.STAGE, translate.STAGE, classify.STAGE, report.STAGE)
}

__all__ = ["STAGES", "StageContext", "StageKind", "StageResult"]
