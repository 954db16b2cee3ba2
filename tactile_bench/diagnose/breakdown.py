"""Where the diagnosis spends its time: the names of its timed spans and the breakdown table.

``run.diagnose`` keeps a ``sensor.timing.SpanTimer`` active while it runs; the steps mark
their work with ``timed_span(NAME)`` using the constants below (a no-op when no timer is
active: ``explain_gap`` called on its own pays one global lookup per span). Spans nest, and
a span's ``seconds`` exclude the spans opened inside it, so the seconds of all spans add up
to the timed total; ``inclusive_seconds`` count them in (a fit's renders, its gap metric).

The spans sit around per-candidate, per-round or per-render work, never per pixel. With
``diagnose --workers N`` the fits' spans are the workers' own, summed over them, and this
process's wait for them is ``WAIT_WORKERS``: the seconds then add up to more than the wall.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tactile_bench.sensor.timing import SpanTimer

#: the diagnosis's own time outside every other span (the split, hashing, the result)
DIAGNOSE = "diagnose"
#: the "where" analysis (all pairs, then the held-out ones before / after the effects)
WHERE = "where"
#: ``explain_gap`` outside the spans below (checks, the Shapley shares' point values)
WHICH = "which"
#: the background correction's row (the sim's own no-contact frame against the measured)
BACKGROUND = "which.background"
#: the selected set's differentiable parameters refitted jointly
JOINT_REFIT = "which.joint_refit"
#: each selected effect replaced by its strong rivals, refitted (``_swapped_rivals``)
SWAPPED_RIVALS = "which.swapped_rivals"
#: the floor and the unexplained share (``_answer``)
ANSWER = "which.answer"
#: every subset of the selection refitted for the Shapley shares (``_coalition_gaps``)
SHAPLEY_COALITIONS = "which.shapley_coalitions"
#: the depth-split check outside its own fits (``stability.check``)
DEPTH_SPLIT = "which.depth_split"
#: every bootstrap interval: shrinks, paired differences, Shapley shares
BOOTSTRAP = "bootstrap"
#: this process waiting on fits run in worker processes (``diagnose.workers``); the spans
#: inside those fits are the workers' own, summed over them
WAIT_WORKERS = "which.waiting_on_workers"
#: the candidate simulator's renders (``simulate.render``): in fits, scores and figures
RENDER = "simulate.render"
#: the optical-response lookup refitted under a geometry (``simulate.lookup_for``)
RESPONSE_LOOKUP = "simulate.response_lookup"
#: the gap measure of rendered draws against the real images (``gapfit.pair_gap``)
GAP = "gapfit.gap"
#: ``how_far`` outside the spans below (pixel SSIM / MSE)
HOW_FAR = "how_far"
#: the KID: its encoder trained on the fit split's real images, features, the two KIDs
KID = "how_far.kid"
#: one downstream classifier trained and tested (one call a training source)
DOWNSTREAM = "how_far.downstream"
#: the held-out renders with the selected effects and the before/after samples
SAMPLES = "samples"
#: report.json and report.html outside their figures
REPORT = "report"
#: the report's figures (matplotlib, PNG encoding)
REPORT_FIGURES = "report.figures"


@dataclass(frozen=True)
class FitSpans:
    """The spans of one run of the selection: the main one, or the depth split's re-run
    (whose fits are then told apart from the main ones)."""

    setup: str  # the splits as scenes, the plain sim's gap, the pairs' noise
    candidate_fit: str  # one candidate fitted alone (and scored on the held-out split)
    refit: str  # one candidate refitted with the effects already selected
    select: str  # the selection's rounds outside the refits (picks, rivals, screening)


MAIN_FIT = FitSpans("which.setup", "which.candidate_fit", "which.refit", "which.select")
DEPTH_SPLIT_FIT = FitSpans(
    "which.depth_split.setup",
    "which.depth_split.candidate_fit",
    "which.depth_split.refit",
    "which.depth_split.select",
)


def breakdown(timer: SpanTimer) -> dict[str, dict[str, Any]]:
    """{span: {"calls", "seconds", "inclusive_seconds"}}, most seconds first (wall time;
    ``seconds`` exclude nested spans, so they add up to the timed total)."""
    rows = {
        name: {
            "calls": int(timer.calls.get(name, 0)),
            "seconds": max(seconds, 0.0),
            "inclusive_seconds": max(timer.inclusive.get(name, seconds), 0.0),
        }
        for name, seconds in timer.wall.items()
    }
    return dict(sorted(rows.items(), key=lambda kv: -kv[1]["seconds"]))


def breakdown_lines(rows: dict[str, dict[str, Any]], top: int | None = None) -> list[str]:
    """The breakdown as text, one span a line, most seconds first (``top``: only those)."""
    total = sum(r["seconds"] for r in rows.values()) or 1.0
    lines = [f"  {'span':<36} {'calls':>7} {'seconds':>9} {'share':>6} {'incl. s':>9}"]
    for name, r in list(rows.items())[:top]:
        lines.append(
            f"  {name:<36} {r['calls']:>7d} {r['seconds']:>9.2f} "
            f"{100 * r['seconds'] / total:>5.1f}% {r['inclusive_seconds']:>9.2f}"
        )
    return lines
