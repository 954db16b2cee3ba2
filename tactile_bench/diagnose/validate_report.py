"""Summary figures and the Markdown report of ``validate-diagnosis``."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from tactile_bench.diagnose.gapfit import GAP_METRIC
from tactile_bench.diagnose.which import FLAG_UNEXPLAINED, MIN_SHARE
from tactile_bench.io import atomic_write_json, atomic_write_text

TOP1_TARGET = 0.9


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Top-1 accuracy, ranks, two-effect and out-of-catalogue outcomes over the case rows."""
    singles = [r for r in rows if r["kind"] == "single"]
    doubles = [r for r in rows if r["kind"] == "double"]
    outs = [r for r in rows if r["kind"] == "out_of_catalogue"]
    told = [r for r in rows if r["kind"] == "named_or_confusable"]
    hits = sum(r["passed"] for r in singles)
    ranks = [rank for r in singles for rank in r["rank_of_true"].values()]
    blamed = sum(r["blamed_with_high_confidence"] for r in outs)
    accuracy = hits / len(singles) if singles else 0.0
    return {
        "n_single": len(singles),
        "top1_hits": hits,
        "top1_accuracy": round(accuracy, 4),
        "mean_rank_of_true": round(statistics.mean(ranks), 3) if ranks else float("nan"),
        "median_shrink_single": round(statistics.median(r["shrink"] for r in singles), 4)
        if singles
        else float("nan"),
        "n_double": len(doubles),
        "doubles_both_found": sum(r["passed"] for r in doubles),
        "n_out": len(outs),
        "out_flagged": sum(r.get("flagged", r["residual_flagged"]) for r in outs),
        "out_blamed_high_confidence": blamed,
        "n_told_apart": len(told),
        "told_apart": sum(r["passed"] for r in told),
        "targets": {
            "top1_at_least_90pct": accuracy >= TOP1_TARGET,
            "no_out_of_catalogue_blamed_with_high_confidence": blamed == 0,
        },
        "gap_metric": GAP_METRIC,
        "rules": {
            "selection": f"adds an effect while it removes >= {MIN_SHARE:.0%} of the initial "
            "held-out gap (once a stochastic effect is selected, of that gap less the "
            "selected model's own randomness) and its bootstrap 95% CI lower bound is > 0",
            "flag": f"flagged when the unexplained share > {FLAG_UNEXPLAINED}, or when the "
            "selection re-run with the shallowest presses fitted and the deepest held out names "
            "first an effect it neither selects nor finds confusable (unstable)",
            "blamed_with_high_confidence": "an out-of-catalogue case with an effect selected "
            "and nothing flagged",
            "named_or_confusable": "a lens blur (noise after it) or a blur + elastic spread "
            "passes when each of its effects is selected or found confusable with a selected "
            "one: never left out while another is named with a confident interval",
        },
    }


def _fmt_params(fitted_vs_true: dict[str, dict[str, list[Any]]]) -> str:
    parts = []
    for effect, values in fitted_vs_true.items():
        pairs = ", ".join(f"{k} {t:.3g}/{f:.3g}" for k, (t, f) in values.items() if f is not None)
        parts.append(f"{effect}: {pairs}")
    return "; ".join(parts)


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    s = summary
    suites = s.get("suites") or {"own": s}
    lines = [
        "# Gap diagnosis on withheld effects (`validate-diagnosis`)",
        "",
        f"{s['n_pairs']} braille pairs per case ({s['size']} x {s['size']}), half to fit, half "
        f"held out; seed {s['seed']}; {'quick' if s['quick'] else 'full'} run, "
        f"{s['seconds']:.0f} s in all. The diagnosis sees only the paired data.",
        "",
        "- **own suite**: sim = the surrogate with no effect; real = the same contacts with the "
        "planted effect(s) at random parameters (25-100% of the way from neutral to a bound).",
        "- **foreign suite**: sim and real by a renderer written apart from the catalogue "
        "(`tactile_bench/diagnose/foreign.py`: its own lights and shading law, or the real "
        "DIGIT's calibration and no-contact frame; its own implementation of each effect, camera "
        "effects on the no-contact frame too), with the sim's own no-contact frame (`own`) or "
        "composited onto the measured one (`composited`).",
        "",
        f"Gap measure: {s['gap_metric']}. Rules: {s['rules']['selection']}; {s['rules']['flag']}.",
    ]
    if s.get("skipped"):
        lines += ["", f"Skipped: {s['skipped']}."]
    for name, sub in suites.items():
        lines += ["", f"## {name.capitalize()} suite", "", *_summary_lines(sub), ""]
        lines += _case_table([r for r in rows if r.get("suite", "own") == name])
    lines += ["", "## What the diagnosis got wrong, and why", ""]
    lines += [_failure(r) for r in rows if not r["passed"]] or ["Every case passed."]
    confusable = [
        f"- **{r['case']}**: {r['runner_up']['effect']} alone removes "
        f"{r['runner_up']['shrink']:.1%} of the gap (the planted effect "
        f"{r['single_shrink_of_true'][r['planted_names'][0]]:.1%})"
        for r in rows
        if r["kind"] == "single"
        and r["passed"]
        and r["runner_up"]
        and r["runner_up"]["shrink"] >= CONFUSABLE_SHARE
        and r["planted_names"][0] in r["single_shrink_of_true"]
    ]
    lines += [
        "",
        "## Near confusions",
        "",
        f"Single plants where another candidate, fitted alone, also removes at least "
        f"{CONFUSABLE_SHARE:.0%} of the gap: the effect was identified by the margin between "
        "the two, not because the other had nothing to say.",
        "",
    ]
    lines += confusable or ["None."]
    lines += ["", "## Reading the figures", "", *NOTES]
    return "\n".join(lines) + "\n"


def _summary_lines(s: dict[str, Any]) -> list[str]:
    return [
        f"- top-1 identification of single planted effects: **{s['top1_hits']}/{s['n_single']}"
        f" ({100 * s['top1_accuracy']:.1f}%)** (target >= 90%: "
        f"{'met' if s['targets']['top1_at_least_90pct'] else 'NOT met'})",
        f"- mean rank of the true effect among all candidates fitted alone: "
        f"{s['mean_rank_of_true']:.2f}",
        f"- median held-out gap shrink, single plants: {s['median_shrink_single']:.3f}",
        f"- two-effect plants with both effects found: {s['doubles_both_found']}/{s['n_double']}",
        f"- out-of-catalogue plants flagged: {s['out_flagged']}/{s['n_out']};"
        f" blamed on a wrong effect with high confidence: {s['out_blamed_high_confidence']} "
        f"(target 0: {'met' if s['out_blamed_high_confidence'] == 0 else 'NOT met'})",
    ] + (
        [
            f"- lens blur and blur + elastic spread plants with each effect named or found "
            f"confusable (never blamed on the other): {s['told_apart']}/{s['n_told_apart']}"
        ]
        if s.get("n_told_apart")
        else []
    )


def _case_table(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| case | kind | expected | background share | selected (shrink ~ confusable) | "
        "Shapley share [95% CI] | rank of true | gap before -> after | unexplained | flagged | "
        "MSE before -> after | fitted vs true (true/fitted) | passed | s |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        confusable = r.get("confusable", {})
        selected = ", ".join(
            f"{e} ({v:.3f}{' ~ ' + ' / '.join(confusable[e]) if confusable.get(e) else ''})"
            for e, v in zip(r["selected"], r["selected_shrink"], strict=True)
        )
        ranks = ", ".join(f"{e} {k}" for e, k in r["rank_of_true"].items()) or "-"
        shapley = ", ".join(
            f"{e} {v[0]:.3f} [{v[1]:.3f}, {v[2]:.3f}]" for e, v in r.get("shapley", {}).items()
        )
        px = r["pixel"]
        share = r.get("background_share")
        lines.append(
            f"| {r['case']} | {r['kind']} | {r.get('expected', '-')} | "
            f"{'-' if share is None else f'{share:.3f}'} | {selected or 'none'} | "
            f"{shapley or '-'} | {ranks} | "
            f"{r['gap_before']:.3g} -> {r['gap_after']:.3g} | {r['unexplained']:.3f} | "
            f"{_flag(r)} | "
            f"{px['before']['mse']:.2f} -> {px['after']['mse']:.2f} | "
            f"{_fmt_params(r['fitted_vs_true']) or '-'} | {'yes' if r['passed'] else 'NO'} | "
            f"{r['seconds']:.0f} |"
        )
    return lines


def _flag(r: dict[str, Any]) -> str:
    """yes (residual), unstable (depth split names X first), or no."""
    if r.get("unstable"):
        return f"unstable ({r['depth_split_first']})"
    return "yes" if r["residual_flagged"] else "no"


CONFUSABLE_SHARE = 0.5
NOTES = (
    "- Pixel MSE cannot see stochastic effects: adding the right camera noise to the sim "
    "*raises* its MSE to the real images, which is why the diagnosis measures the gap as "
    "structure + texture. For those cases the MSE column goes up while the gap goes down.",
    "- The shrink of an effect is measured on the held-out half only; its 95% CI resamples "
    "those pairs.",
    "- `~ X` after a selected effect: a rival at the same round that the held-out pairs cannot "
    "tell from it (the paired bootstrap 95% CI of the difference in their shrink reaches 0); "
    "the diagnosis reports the set (`confusable_with`) instead of claiming the first.",
    "- `unexplained` is counted above a floor no model can remove: the larger of the gap the "
    "pairs' own frame-to-frame noise makes against itself and, for stochastic effects, the "
    "gap the fitted model leaves on data drawn from itself.",
    "- flagged `unstable (X)`: re-run with the shallowest half of the presses fitted and the "
    "deepest half held out (100 pairs at most), the selection names X first, which it "
    "neither selects nor finds confusable: the explanation depends on the presses it was "
    "fitted on.",
    "- pose_error is fitted as a constant misregistration and press_error as a depth scale "
    "and offset; their random parts per contact are not fitted, so part of a planted "
    "jitter stays unexplained.",
    "- background share: the part of the plain sim's gap the measured no-contact frame removes "
    "(no parameter fitted); `-` when the sim was composited onto it. The ranking, gap and "
    "unexplained share are on what it leaves; a plant that changes only the no-contact frame "
    "(unit_background) is expected to be named by that line (`measured_background`).",
)


def _failure(r: dict[str, Any]) -> str:
    """One line on a failed case, with the figures that explain it."""
    gap = r["gap_before"]
    parts = []
    for e, share in r["single_shrink_of_true"].items():
        if e in r["selected"]:
            continue
        parts.append(
            f"{e} alone removes {share:.1%} of the gap ({share * gap:.3g} grey level^2, rank "
            f"{r['rank_of_true'][e]} of the candidates)"
        )
    why = []
    if gap < 1.0:
        why.append(
            f"the planted effect changes the images by {gap:.2g} grey level^2 in all (an RMS "
            f"of {gap**0.5:.2f} grey levels, about 8-bit rounding): invisible at this size"
        )
    elif any(s < MIN_SHARE for s in r["single_shrink_of_true"].values()):
        why.append(f"below the {MIN_SHARE:.0%} share an effect needs to be selected")
    if not parts:
        planted = [e for e in r["planted_names"] if e in r["selected"]]
        parts = [f"{e} selected, not first" for e in planted] or ["planted effect not a candidate"]
    return (
        f"- **{r['case']}**: selected {', '.join(r['selected']) or 'nothing'}; "
        f"{'; '.join(parts)}"
        f"{': ' + '; '.join(why) if why else ''}. Unexplained {r['unexplained']:.3f}."
    )


def write_report(out: Path, summary: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    """``validation.json`` (summary + rows) and ``validation.md`` into ``out``."""
    atomic_write_json(out / "validation.json", {"summary": summary, "cases": rows})
    atomic_write_text(out / "validation.md", markdown(summary, rows))
