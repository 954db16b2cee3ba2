"""Stage ``sensor_report``: one report on a user's own sensor (``recipes/own_sensor.yaml``).

What a researcher with their own sensor wants on one page: the calibrated profile (what was
fitted, held-out figures before and after), the gap diagnosis (which effects, how much each
removes, what is left), the translators compared on the held-out real frames beside the
profile (SSIM, MSE, KID), the sample grid and the press-count curve, and where the time went.
Writes ``report.md`` / ``report.html`` / ``report.json``, published to the run directory.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from pydantic import Field

from tactile_bench.hardware import machine_compute
from tactile_bench.io import atomic_write_json
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind, StageResult
from tactile_bench.pipeline.stages.report import machine_line
from tactile_bench.report.document import Document

METRICS = (("mse", "MSE", 2), ("ssim", "SSIM", 4), ("contact_mse", "contact MSE", 2))


class SensorReportConfig(StageConfig):
    """The report's title and the sentence under it."""

    title: str = Field(
        default="Your sensor: calibration, gap and translators", description="heading of the report"
    )
    description: str = Field(default="", description="a sentence under the heading")


def _json(result: StageResult | None, output: str) -> dict[str, Any] | None:
    if result is None or output not in result.outputs:
        return None
    return json.loads(result.path(output).read_text())


def _mean(value: Any) -> float:
    return float(value["mean"]) if isinstance(value, dict) else float(value)


def _calibration(doc: Document, cal: dict[str, Any], profile_path: Path) -> None:
    doc.heading("The calibrated profile")
    effects = cal["profile"]["effects"]
    doc.paragraph(
        f"Fitted on {cal['n_fit']} of {cal['n_pairs']} pairs ({cal['n_heldout']} held out, "
        f"seed {cal['seed']}) at {cal['size']} px: the no-contact frame "
        f"({cal['background_k']} x {cal['background_k']} cosine terms), the optical response "
        "fitted from the real frames, and the effects the diagnosis selected: "
        + (", ".join(f"`{n}` {p}" for n, p in effects.items()) or "none")
        + f". Use it as `--profile {profile_path}` (render, ground) or "
        f"`second_unit: {profile_path}` (braille_data)."
    )
    held = cal.get("heldout")
    if not held:
        doc.paragraph(cal.get("heldout_note") or "No held-out pairs: nothing measures it.")
        return
    doc.table(
        ["held-out pairs", *(label for _, label, _ in METRICS)],
        [
            [name, *(f"{_mean(held[name][key]):.{d}f}" for key, _, d in METRICS)]
            for name in ("sim", "profile")
        ],
    )


def _diagnosis(doc: Document, diag: dict[str, Any]) -> None:
    doc.heading("The gap diagnosis")
    rows = [
        [r["effect"], f"{r['shrink']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]"]
        for r in diag["ranking"]
    ]
    doc.table(["effect (in order of selection)", "shrink of the held-out gap [95% CI]"], rows)
    flagged = " (flagged)" if diag.get("flagged") else ""
    doc.paragraph(
        f"{diag['n_pairs']} pairs, {diag['split']['n_fit']} fitted / {diag['split']['n_held']} "
        f"held out; unexplained share of the gap: {diag['unexplained']:.3f}{flagged}. "
        "The full answer (where the gap lies, Shapley shares, confusable effects): the "
        "diagnose stage's report.html."
    )


def _translators(doc: Document, rows: list[dict[str, Any]], n: int) -> None:
    doc.heading("Translators on the held-out real frames")
    doc.table(
        ["translator", "stage", "SSIM", "MSE", "KID, own encoder (± std)"],
        [
            [
                r["translator"],
                r["stage"],
                f"{r['ssim']:.3f}",
                f"{r['mse']:.2f}",
                f"{r['kid']:.4f} ± {r['kid_std']:.4f}",
            ]
            for r in rows
        ],
    )
    doc.paragraph(
        f"Each row against the real image of each of the {n} held-out pairs (0-255). "
        "`profile` is the calibrated profile's rendering on the real no-contact frame, fitted "
        "on the same pairs as the learned translators; the plain simulator's figures are the "
        "calibration table's sim row. KID: mean ± std over subsets of half the held-out set."
    )


def _copy(result: StageResult | None, output: str, target: Path) -> Path | None:
    if result is None or output not in result.outputs:
        return None
    shutil.copyfile(result.path(output), target)
    return target


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: SensorReportConfig = ctx.config
    calibration = ctx.input("calibration")
    compare = ctx.optional_input("similarity")
    cal = _json(calibration, "calibration_json") or {}
    diag = _json(ctx.optional_input("diagnosis"), "report_json")
    similarity = _json(compare, "similarity_json")
    doc = Document(config.title)
    if config.description:
        doc.paragraph(config.description)
    _calibration(doc, cal, calibration.path("profile"))
    curve = _copy(calibration, "curve", ctx.directory / "curve.png")
    if curve is not None:
        doc.figure(curve, "Held-out contact MSE against the number of fitted presses")
    if diag is not None:
        _diagnosis(doc, diag)
    if similarity is not None:
        _translators(doc, similarity["rows"], similarity["n"])
    samples = _copy(compare, "samples", ctx.directory / "samples.png")
    if samples is not None:
        doc.figure(samples, "Held-out pairs: depth | real | each translator")
    doc.heading("Where the time went")
    doc.paragraph(machine_line(machine_compute()))
    doc.table(
        ["stage", "kind", "wall time (s)", "cached in this run"],
        [
            [r.name, r.kind, f"{r.wall_time_s:.1f}", "yes" if r.cached else "no"]
            for r in ctx.previous
        ],
    )
    doc.write(ctx.directory / "report.md", ctx.directory / "report.html", links_from=ctx.run_dir)
    summary = {
        "calibration": {k: cal.get(k) for k in ("n_fit", "n_heldout", "selected", "heldout")},
        "diagnosis": None
        if diag is None
        else {"ranking": diag["ranking"], "unexplained": diag["unexplained"]},
        "translators": None if similarity is None else similarity["rows"],
        "stages": {r.name: round(r.wall_time_s, 1) for r in ctx.previous},
        "machine": machine_compute(),
    }
    atomic_write_json(ctx.directory / "report.json", summary)
    outputs = {"report_md": "report.md", "report_html": "report.html", "report_json": "report.json"}
    outputs |= {p.stem: p.name for p in (curve, samples) if p is not None}
    return outputs, {"translators": len(summary["translators"] or [])}


STAGE = StageKind(
    name="sensor_report",
    description="your sensor's report: the calibrated profile, the gap diagnosis and the "
    "translators on held-out real frames",
    config_model=SensorReportConfig,
    run=_run,
    input_slots={"calibration": True, "diagnosis": False, "similarity": False},
    publish=("report_md", "report_html"),
    waits_for_earlier=True,  # its timing table lists every stage before it
)
