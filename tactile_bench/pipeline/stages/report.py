"""Stage ``report``: the paper's table with ours beside it, as a report a researcher would publish.

Writes ``results.json`` / ``results.md`` (the table), ``table.json`` (rows with mean and std
of each metric, SSIM/MSE where a translator made the training images, stage wall times) and
``report.md`` (published to the run directory, its figure links relative to it) and a
self-contained ``report.html``: the table, the paper's qualitative claims
checked one by one against our numbers, image similarity, per-class accuracy, confusion
matrices, sample images, what varies with the seeds, and where the time went.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.hardware import machine_compute
from tactile_bench.io import atomic_write_json, atomic_write_text
from tactile_bench.pipeline.provenance import machine, versions
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind, StageResult
from tactile_bench.report.document import Document
from tactile_bench.report.figures import per_class_heatmap_png
from tactile_bench.report.shape import (
    DECIDED_AT,
    EXPERIMENTS,
    EXPERIMENTS_DOC,
    shape_checks,
)
from tactile_bench.report.table import (
    PAPER_TABLE,
    columns,
    results_markdown,
    second_unit_note,
    table_cells,
)


class ReportConfig(StageConfig):
    """The report's title and the sentence under it."""

    title: str = Field(
        default="Braille classification on the real test set", description="heading of the report"
    )
    description: str = Field(default="", description="a sentence under the heading")


def _row(result: StageResult) -> dict[str, Any]:
    metrics = json.loads(result.path("metrics").read_text())
    summary = metrics["summary"]
    return {
        "row": summary["row"],
        "accuracy": summary["accuracy"],
        "precision": summary["precision"],
        "recall": summary["recall"],
        "sim_accuracy": summary["test_sim_accuracy"],
        # the same contacts through a second unit (braille_data second_unit); older runs lack it
        "second_unit_accuracy": summary.get("second_unit_accuracy"),
        "second_unit": summary.get("second_unit"),
        "extra": {
            "stage": result.name,
            "seeds": summary["seeds"],
            "n_train": summary["n_train"],
            "n_test": summary["n_test"],
            "heldout_accuracy": summary["heldout_accuracy"],
            "tested_on": summary.get("tested_on"),  # "real", or None: surrogate frames
        },
        "per_class": [s["test"]["per_class_accuracy"] for s in metrics["per_seed"]],
    }


def _similarity(ctx: StageContext) -> list[dict[str, Any]]:
    compare = ctx.optional_input("similarity")
    if compare is None:
        return []
    return json.loads(compare.path("similarity_json").read_text())["rows"]


def _versions() -> dict[str, str | None]:
    """What the report's numbers were computed with (the same record as run.json)."""
    return {**versions(), "platform": machine()["platform"]}


def _per_class_figure(rows: list[dict[str, Any]], path: Path) -> Path:
    n_classes = max(len(r["per_class"][0]) for r in rows)
    matrix = np.full((len(rows), n_classes), np.nan)
    for i, r in enumerate(rows):
        per_seed = np.array(
            [[np.nan if v is None else v for v in seed] for seed in r["per_class"]], dtype=float
        )
        matrix[i, : per_seed.shape[1]] = np.nanmean(per_seed, axis=0)
    labels = [r["row"] for r in rows]
    return per_class_heatmap_png(matrix, labels, list(CHARACTERS[:n_classes]), path)


def _timing(previous: list[StageResult]) -> tuple[list[list[str]], float]:
    rows = [
        [r.name, r.kind, f"{r.wall_time_s:.1f}", "yes" if r.cached else "no", _precision(r)]
        for r in previous
    ]
    return rows, float(sum(r.wall_time_s for r in previous))


def processes_note(previous: list[StageResult]) -> str:
    """A sentence for the stages that trained on several processes (DDP), whose optimizer
    steps each averaged that many batches: their effective batch is larger than the
    config's ``batch_size``, and so their numbers may differ from one process's. "" when
    every stage trained on one process."""
    by_count: dict[int, list[str]] = {}
    for result in previous:
        count = int(result.metrics.get("processes") or 1)
        if count > 1:
            by_count.setdefault(count, []).append(result.name)
    parts = [
        f"{', '.join(names)} trained on {count} processes (DDP): each optimizer step averaged "
        f"{count} batches, an effective batch of {count} x the configured batch_size"
        for count, names in sorted(by_count.items())
    ]
    return ("; ".join(parts) + ".") if parts else ""


def _precision(result: StageResult) -> str:
    """The precision a stage's networks trained or sampled in; "—" for stages without."""
    value = result.metrics.get("compute_precision")
    return "—" if value is None else str(value)


def machine_line(info: dict[str, Any]) -> str:
    """One line on what the timings and the precision depend on (``hardware.machine_compute``)."""
    native = "yes" if info["native_bf16"] else "no"
    threads = info["torch_threads"]
    caps = ", ".join(f"{k}={v}" for k, v in (info.get("isa_caps") or {}).items())
    return (
        f"Machine: CPU capability {info['cpu_capability']}, native bf16 {native}, {threads} "
        f"thread{'s' * (threads != 1)} a stage; precision: auto -> {info['auto_precision']}"
        + (f" (instruction sets capped: {caps})" if caps else "")
    )


def _document(
    ctx: StageContext,
    rows: list[dict[str, Any]],
    similarity: list[dict[str, Any]],
    checks: list[dict[str, Any]],
    figures: dict[str, Path],
) -> Document:
    config: ReportConfig = ctx.config
    doc = Document(config.title)
    if config.description:
        doc.paragraph(config.description)
    doc.heading("Classification on the real test set, ours beside the paper")
    doc.table(columns(rows), table_cells(rows))
    seeds = sorted({s for r in rows for s in r["extra"]["seeds"]})
    doc.paragraph(
        "Accuracy is micro (% of test images); precision and recall are macro over characters. "
        f"Each row is the mean ± sample std over classifier seeds {seeds}: the seed sets the "
        "classifier's initial weights, batch order and held-out split. The data, the "
        "translators and the real fine-tuning subsets are fixed by the recipe seed "
        f"({ctx.seed}), so the ± shows classifier training noise only, not the variation "
        "between translator trainings or data draws. The sim column scores the same "
        "classifiers on the same test contacts rendered by the simulator." + second_unit_note(rows)
    )
    doc.heading("The paper's claims, checked on our numbers")
    doc.table(
        ["claim", "measured", "holds", "decided by the seeds"],
        [[c["claim"], c["measured"], "yes" if c["holds"] else "NO", _decided(c)] for c in checks],
    )
    doc.paragraph(
        "A claim is decided by the seeds when the difference it rests on is more than "
        f"{DECIDED_AT:g} standard errors (from the rows' seed stds) from where it would turn; "
        "an undecided claim holds or fails within classifier training noise."
    )
    explained = [
        f"{c['claim']}: {'holds' if c['holds'] else 'fails'} here"
        f"{', within seed noise' if c['decided'] is False else ''}; the A/B experiments on "
        f"this project's surrogate: {EXPERIMENTS_DOC}, section '{EXPERIMENTS[c['claim']]}'"
        for c in checks
        if c["claim"] in EXPERIMENTS and (not c["holds"] or c["decided"] is False)
    ]
    if explained:
        doc.paragraph("Failing or undecided claims, and where the experiments behind them are:")
        doc.bullets(explained)
    if similarity:
        doc.heading("Image similarity on the braille test set")
        doc.table(
            ["translator", "stage", "SSIM", "MSE", "KID (own encoder)", "paper SSIM", "paper MSE"],
            [
                [
                    s["translator"],
                    s["stage"],
                    f"{s['ssim']:.3f}",
                    f"{s['mse']:.2f}",
                    f"{s['kid']:.4f} ± {s['kid_std']:.4f}",
                    "—" if s.get("paper_ssim") is None else f"{s['paper_ssim']:.3f}",
                    "—" if s.get("paper_mse") is None else f"{s['paper_mse']:.2f}",
                ]
                for s in similarity
            ],
        )
    if "samples" in figures:
        doc.figure(figures["samples"], "Test contacts: depth | real | each translator")
    doc.heading("Per-class accuracy")
    doc.figure(figures["per_class"], "Accuracy per character and row (mean over seeds)")
    doc.heading("Confusion matrices (first seed)")
    for row_id, path in figures.items():
        if row_id.startswith("confusion:"):
            doc.figure(path, f"{row_id.split(':', 1)[1]}: confusion on the real test set")
    doc.heading("Where the time went")
    timing, total = _timing(ctx.previous)
    doc.paragraph(
        machine_line(machine_compute()) + " (bf16 autocast only where the CPU has bf16 "
        "arithmetic, AVX-512-BF16 or AMX; elsewhere it is emulated and many times slower)."
    )
    doc.table(["stage", "kind", "wall time (s)", "cached in this run", "precision"], timing)
    doc.paragraph(
        f"Sum of stage wall times: {total:.0f} s ({total / 60:.1f} min); a cached stage shows "
        "the time it took when it ran, and stages run side by side (the recipe's `jobs`) "
        "overlap, so the run itself can take less. The precision column is the one each "
        "stage's networks trained or sampled in (— for stages without)."
    )
    if processes_note(ctx.previous):
        doc.paragraph(processes_note(ctx.previous))
    doc.heading("Reproducibility")
    doc.bullets([f"{k}: {v}" for k, v in _versions().items()] + [f"recipe seed: {ctx.seed}"])
    return doc


def _decided(check: dict[str, Any]) -> str:
    if check["decided"] is None:
        return "—"
    if check["decided"]:
        return "yes"
    return (
        f"no: {abs(check['gap']):.2f} points from where it turns, "
        f"{DECIDED_AT:g} s.e. {DECIDED_AT * check['gap_error']:.2f}"
    )


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: ReportConfig = ctx.config
    rows = [_row(result) for result in ctx.inputs["rows"]]
    similarity = _similarity(ctx)
    checks = shape_checks(rows, similarity)
    figures: dict[str, Path] = {
        "per_class": _per_class_figure(rows, ctx.directory / "per_class.png")
    }
    for result in ctx.inputs["rows"]:
        if "confusion" in result.outputs:
            target = ctx.directory / f"confusion_{result.name}.png"
            shutil.copyfile(result.path("confusion"), target)
            figures[f"confusion:{result.name}"] = target
    compare = ctx.optional_input("similarity")
    if compare is not None and "samples" in compare.outputs:
        figures["samples"] = ctx.directory / "samples.png"
        shutil.copyfile(compare.path("samples"), figures["samples"])

    table_rows = [{k: v for k, v in r.items() if k != "per_class"} for r in rows]
    atomic_write_json(ctx.directory / "results.json", {"title": config.title, "rows": table_rows})
    note = processes_note(ctx.previous)
    table_md = results_markdown(table_rows, config.title) + (f"{note}\n" if note else "")
    atomic_write_text(ctx.directory / "results.md", table_md)
    timing, total = _timing(ctx.previous)
    by_translator = {s["stage"]: s for s in similarity}
    atomic_write_json(
        ctx.directory / "table.json",
        {
            "title": config.title,
            "rows": [
                {
                    "row": r["row"],
                    "paper": vars(PAPER_TABLE[r["row"]]) if r["row"] in PAPER_TABLE else None,
                    **{m: r[m] for m in ("accuracy", "precision", "recall", "sim_accuracy")},
                    "second_unit_accuracy": r["second_unit_accuracy"],
                    "second_unit": r["second_unit"],
                    "stage": r["extra"]["stage"],
                    "seeds": r["extra"]["seeds"],
                }
                for r in rows
            ],
            "similarity": list(by_translator.values()),
            "checks": checks,
            "stages": [
                {
                    "name": r.name,
                    "kind": r.kind,
                    "wall_time_s": float(t[2]),
                    "cached": r.cached,
                    "compute_precision": r.metrics.get("compute_precision"),
                    "processes": int(r.metrics.get("processes") or 1),
                }
                for r, t in zip(ctx.previous, timing, strict=True)
            ],
            "total_stage_time_s": total,
            "machine": machine_compute(),
            "versions": _versions(),
            "seed": ctx.seed,
        },
    )
    _document(ctx, rows, similarity, checks, figures).write(
        ctx.directory / "report.md", ctx.directory / "report.html", links_from=ctx.run_dir
    )
    outputs = {
        "results_json": "results.json",
        "results_md": "results.md",
        "table_json": "table.json",
        "report_md": "report.md",
        "report_html": "report.html",
        "per_class": "per_class.png",
    }
    outputs |= {k.replace(":", "_"): v.name for k, v in figures.items() if k != "per_class"}
    return outputs, {
        "rows": len(rows),
        "checks_failed": sum(not c["holds"] for c in checks),
        "checks_undecided": sum(c["decided"] is False for c in checks),
    }


STAGE = StageKind(
    name="report",
    description="the table beside the paper, claim checks, figures, timings: report.md/.html",
    config_model=ReportConfig,
    run=_run,
    input_slots={"rows": True, "similarity": False},
    publish=("results_json", "results_md", "table_json", "report_md", "report_html"),
    waits_for_earlier=True,  # its timing table lists every stage before it
)
