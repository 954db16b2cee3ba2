"""Stage ``report``: gather classifier rows into results.json / results.md beside the paper."""

from __future__ import annotations

import json
from typing import Any

from tactile_bench.io import atomic_write_json, atomic_write_text
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.report.table import results_markdown


class ReportConfig(StageConfig):
    """The report's title."""

    title: str = "Braille classification on the real test set"


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    rows = []
    for result in ctx.inputs["rows"]:
        summary = json.loads(result.path("metrics").read_text())["summary"]
        rows.append(
            {
                "row": summary["row"],
                "accuracy": summary["accuracy"],
                "precision": summary["precision"],
                "recall": summary["recall"],
                "sim_accuracy": summary["test_sim_accuracy"],
                "extra": {
                    "stage": result.name,
                    "seeds": summary["seeds"],
                    "n_train": summary["n_train"],
                    "n_test": summary["n_test"],
                    "heldout_accuracy": summary["heldout_accuracy"],
                },
            }
        )
    atomic_write_json(ctx.directory / "results.json", {"title": ctx.config.title, "rows": rows})
    atomic_write_text(ctx.directory / "results.md", results_markdown(rows, ctx.config.title))
    return {"results_json": "results.json", "results_md": "results.md"}, {"rows": len(rows)}


STAGE = StageKind(
    name="report",
    description="collect classifier rows into results.json and results.md, paper beside",
    config_model=ReportConfig,
    run=_run,
    input_slots={"rows": True},
    publish=("results_json", "results_md"),
)
