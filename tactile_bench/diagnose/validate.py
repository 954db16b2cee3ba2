"""Proof on withheld effects: plant an effect in "real" data, diagnose blind, compare.

``python -m tactile_bench validate-diagnosis`` renders braille contacts twice with the
surrogate: sim = ``SurrogateDigit(effects={})`` (no effect), real = the same contacts with the
planted effect(s) at random parameters. The diagnosis (``which.explain_gap``) sees only a
``DiagnosisPairs`` (depth, sim, real, the real unit's no-contact frame, the plain one) and must
name the planted effect. Cases: every candidate alone; two-effect plants; and effects outside
the candidate set (a candidate removed from the set while planted), whose residual must be
flagged rather than blamed on a wrong effect. Writes ``validation.json`` (summary + one row
per case) and ``validation.md``.

Planting rule: every parameter of a planted effect is drawn independently, on a random side
of its neutral value (where the range allows), at a uniform 25-100% of the distance from
neutral to that bound; integer parameters are rounded, ``unit_seed`` is a random integer.

The **foreign suite** (``--suite foreign``) plants effects with a renderer written apart
from the catalogue (``diagnose.foreign``: other lights and shading law, or the real DIGIT's
calibration and no-contact frame; its own implementation of each effect, camera effects on
the no-contact frame too), in both background variants (the sim's own no-contact frame, or
the sim composited onto the measured one). A plant whose catalogue name is not a candidate
is an out-of-catalogue case: it must be flagged, not blamed.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from tactile_bench.diagnose.candidates import DEFAULT_CANDIDATES
from tactile_bench.diagnose.foreign import (
    COMBINED_PLANTS,
    FOREIGN_PLANTS,
    SHADINGS,
    SINGLE_PLANTS,
    VARIANTS,
    foreign_pairs,
    shared_real_available,
)
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.simulate import apply_effects
from tactile_bench.diagnose.validate_report import summarise, write_report
from tactile_bench.diagnose.which import BACKGROUND_LINE, WhichResult, explain_gap
from tactile_bench.effects import EFFECTS
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.geometry.contacts import classifier_test_protocol
from tactile_bench.metrics import ssim_mse
from tactile_bench.sensor.depth import GelSpec, render_depth
from tactile_bench.sensor.heightfield import HeightFieldBank, build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit

DOUBLES: tuple[tuple[str, str], ...] = (
    ("optical_response", "camera_noise"),
    ("elastic_spread", "vignetting"),
    ("led_diffusivity", "shadows"),
    ("defocus_blur", "jpeg"),
)
# planted but not candidates: pose effects (left out by design) and one removed candidate
OUT_OF_CATALOGUE: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("shadows", ("shadows",)),
    ("defocus_blur", ("defocus_blur",)),
)
QUICK_SINGLES = ("optical_response", "vignetting", "camera_noise", "elastic_spread")
# a slightly defocused lens: blur after the optics (the no-contact frame through it too),
# the sensor's noise after the blur (the foreign suite's ranges, in mm at 64 px)
LENS_BLUR: dict[str, dict[str, tuple[float, float]]] = {
    "defocus_blur": {"sigma_mm": (0.15, 0.45)},
    "camera_noise": {"read_noise": (2.0, 5.0), "shot_gain": (0.05, 0.2)},
}
BLUR_AND_SPREAD = ("defocus_blur", "elastic_spread")
# what the diagnosis names for a planted effect that is not itself a candidate
SHOWN_AS = {"unit_background": BACKGROUND_LINE}  # the measured frame replaces the unit's
OWN_SINGLES = (*DEFAULT_CANDIDATES, *SHOWN_AS)
QUICK_FOREIGN = ("blur", "vignetting", "noise", "optics", "barrel")
SUITES = ("own", "foreign")


@dataclass
class Case:
    """One validation case: what is planted and which candidates are withheld."""

    name: str
    kind: str  # "single", "double", "named_or_confusable" or "out_of_catalogue"
    planted: list[str]  # catalogue names (foreign suite: what the plant is in the catalogue)
    removed: tuple[str, ...] = ()
    # named_or_confusable: each of these must be selected or found confusable with a
    # selected effect, never left out while another is named with a confident interval
    required: tuple[str, ...] = ()
    params: dict[str, dict[str, float]] = field(default_factory=dict)
    suite: str = "own"
    foreign: tuple[str, str, str] | None = None  # (plant, shading, variant): foreign suite


def draw_params(name: str, rng: np.random.Generator) -> dict[str, float]:
    """Random parameters of effect ``name`` by the planting rule (module docstring)."""
    out: dict[str, float] = {}
    for p in EFFECTS[name].params:
        if p.name == "unit_seed":
            out[p.name] = float(rng.integers(0, 100_000))
            continue
        sides = [s for s, room in ((1, p.high - p.neutral), (-1, p.neutral - p.low)) if room > 0]
        side = sides[int(rng.integers(len(sides)))]
        room = (p.high if side > 0 else p.low) - p.neutral
        value = p.neutral + float(rng.uniform(0.25, 1.0)) * room
        value = float(round(value)) if p.integer else float(f"{value:.4g}")
        out[p.name] = _float32_in(value, p.low, p.high)
    return out


def _float32_in(value: float, low: float, high: float) -> float:
    """``value`` as a float32 inside [low, high] (``Effect.validate`` checks in float32)."""
    v = np.float32(value)
    if float(v) > high:
        v = np.nextafter(np.float32(high), np.float32(-np.inf))
    if float(v) < low:
        v = np.nextafter(np.float32(low), np.float32(np.inf))
    return float(v)


def make_cases(quick: bool, seed: int, suites: tuple[str, ...] = ("own",)) -> list[Case]:
    """The case list of ``suites`` with drawn parameters (seeded)."""
    cases = _own_cases(quick, seed) if "own" in suites else []
    if "foreign" in suites:
        cases += _foreign_cases(QUICK_FOREIGN if quick else SINGLE_PLANTS, seed)
    # the lens-blur cases last, so every earlier case keeps its index (its data and split)
    if "own" in suites:
        cases += _told_apart_cases(seed)
    if "foreign" in suites:
        cases += _foreign_cases(COMBINED_PLANTS, seed, first=len(SINGLE_PLANTS))
    return cases


def _foreign_cases(plants: tuple[str, ...], seed: int, first: int = 0) -> list[Case]:
    """Each of ``plants`` under each shading and background variant (the real DIGIT's
    shading only where ../shared/real is at hand); ``first``: the first plant's draw index."""
    shadings = [s for s in SHADINGS if s != "polycalib" or shared_real_available()]
    cases = []
    for shading in shadings:
        for variant in VARIANTS:
            for i, plant in enumerate(plants, start=first):
                spec = FOREIGN_PLANTS[plant]
                known = spec.expected in DEFAULT_CANDIDATES or spec.expected in SHOWN_AS
                kind = "single" if known else "out_of_catalogue"
                rng = np.random.default_rng([seed, SHADINGS.index(shading), i, 13])
                cases.append(
                    Case(
                        f"{plant} ({shading}, {variant})",
                        spec.kind if spec.named_as else kind,
                        list(spec.named_as) or [spec.expected or plant],
                        params={plant: spec.draw(rng)},
                        suite="foreign",
                        foreign=(plant, shading, variant),
                        required=spec.named_as,
                    )
                )
    return cases


def _own_cases(quick: bool, seed: int) -> list[Case]:
    singles = QUICK_SINGLES if quick else OWN_SINGLES
    doubles = DOUBLES[:1] if quick else DOUBLES
    outs = OUT_OF_CATALOGUE[:1] if quick else OUT_OF_CATALOGUE
    cases = [Case(n, "single", [n]) for n in singles]
    cases += [Case(" + ".join(d), "double", list(d)) for d in doubles]
    cases += [
        Case(f"{n} (not a candidate)", "out_of_catalogue", [n], removed) for n, removed in outs
    ]
    for i, case in enumerate(cases):
        rng = np.random.default_rng([seed, i, 7])
        case.params = {n: draw_params(n, rng) for n in case.planted}
    return cases


def _told_apart_cases(seed: int) -> list[Case]:
    """A lens blur (noise after it) and a blur + elastic spread double: each must be named or
    found confusable, never blamed on the other with a confident interval."""
    rng = np.random.default_rng([seed, 17])
    lens = {
        name: {k: float(f"{rng.uniform(*bounds):.4g}") for k, bounds in ranges.items()}
        for name, ranges in LENS_BLUR.items()
    }
    double = {name: draw_params(name, rng) for name in BLUR_AND_SPREAD}
    return [
        Case(
            "lens blur (defocus_blur, camera_noise after it)",
            "named_or_confusable",
            list(LENS_BLUR),
            params=lens,
            required=("defocus_blur",),
        ),
        Case(
            " + ".join(BLUR_AND_SPREAD),
            "named_or_confusable",
            list(BLUR_AND_SPREAD),
            params=double,
            required=BLUR_AND_SPREAD,
        ),
    ]


def planted_pairs(
    bank: HeightFieldBank, planted: dict[str, dict[str, float]], n: int, seed: int, size: int
) -> DiagnosisPairs:
    """``n`` braille contacts: sim without effects, real with ``planted`` (seeded)."""
    gel = GelSpec(size=size)
    poses = classifier_test_protocol(bank.chars, n, seed)
    sim_sensor, real_sensor = SurrogateDigit({}), SurrogateDigit(planted)
    streams = np.random.SeedSequence([seed, 11]).generate_state(2)
    sim = sim_sensor.render(bank, poses, gel, torch.Generator().manual_seed(int(streams[0])))
    real = real_sensor.render(bank, poses, gel, torch.Generator().manual_seed(int(streams[1])))
    return DiagnosisPairs(
        depth=render_depth(bank, poses, gel),
        sim=sim.round(),
        real=real.round(),
        background=real_sensor.background(gel).round(),
        sim_background=sim_sensor.background(gel).round(),
        labels=[bank.chars[i] for i in poses.labels.tolist()],
        names=[f"contact_{i:04d}" for i in range(n)],
    )


def case_pairs(
    case: Case, bank: HeightFieldBank, n: int, seed: int, size: int, index: int
) -> tuple[DiagnosisPairs, torch.Tensor, torch.Tensor]:
    """The ``index``-th case's ``n`` pairs and its random fit / held-out halves, seeded by
    (``seed``, ``index``): the same data and split in a full run and when a case is re-run
    alone (``scripts/diagnosis_depth_split.py``)."""
    data_seed = int(np.random.SeedSequence([seed, index, 1009]).generate_state(1)[0])
    if case.foreign is None:
        data = planted_pairs(bank, case.params, n, data_seed, size)
    else:
        plant, shading, variant = case.foreign
        data = foreign_pairs(bank, plant, case.params[plant], n, data_seed, size, shading, variant)
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(data_seed))
    return data, perm[: n // 2], perm[n // 2 :]


def run_case(
    case: Case, bank: HeightFieldBank, n: int, seed: int, size: int, index: int
) -> dict[str, Any]:
    """Plant, diagnose blind, and score one case: a row of validation.json."""
    start = time.perf_counter()
    data, fit_idx, held_idx = case_pairs(case, bank, n, seed, size, index)
    candidates = [c for c in DEFAULT_CANDIDATES if c not in case.removed]
    result = explain_gap(data, fit_idx, held_idx, candidates, seed=seed, progress=False)
    seconds = time.perf_counter() - start
    real = data.real[held_idx]
    after = apply_effects(data, result.selected_params, held_idx, seed, fit_idx)
    pixel = {"before": ssim_mse(data.sim[held_idx], real), "after": ssim_mse(after, real)}
    row = {
        **_case_fields(case, n),
        **_answer_fields(result),
        **_truth_fields(case, result, [e for e in case.planted if e in candidates]),
        **_gap_fields(result),
        "pixel": pixel,
        "seconds": round(seconds, 1),
    }
    return row | verdict(case, row)


def _case_fields(case: Case, n: int) -> dict[str, Any]:
    """What was planted, by which renderer, and what was withheld."""
    return {
        "case": case.name,
        "suite": case.suite,
        "renderer": "surrogate" if case.foreign is None else f"foreign {case.foreign[1]}",
        "variant": "own" if case.foreign is None else case.foreign[2],
        "kind": case.kind,
        "planted": case.params,
        "planted_names": list(case.planted),
        "candidates_removed": list(case.removed),
        "n_pairs": n,
    }


def _answer_fields(result: WhichResult) -> dict[str, Any]:
    """What the diagnosis named: the selection, the first effect (the background line when
    nothing is selected after it) and the runner-up alone."""
    top = result.ranking[0] if result.ranking else result.background
    runner_up = result.singles[1] if len(result.singles) > 1 else None
    return {
        "background_share": round(result.background.shrink, 4) if result.background else None,
        "selected": [r.effect for r in result.ranking],
        "confusable": {r.effect: r.confusable_with for r in result.ranking if r.confusable_with},
        "selected_shrink": [round(r.shrink, 4) for r in result.ranking],
        "shapley": {
            s.effect: [round(s.share, 4), round(s.ci_low, 4), round(s.ci_high, 4)]
            for s in result.shapley
        },
        "top1": top.effect if top else None,
        "top1_ci": [round(top.ci_low, 4), round(top.ci_high, 4)] if top else None,
        "runner_up": {"effect": runner_up.effect, "shrink": round(runner_up.shrink, 4)}
        if runner_up
        else None,
    }


def _truth_fields(case: Case, result: WhichResult, in_set: list[str]) -> dict[str, Any]:
    """Where the planted effects (those among the candidates) rank alone, and their fitted
    parameters against the planted ones (own suite: foreign plants name their own)."""
    singles = {r.effect: r for r in result.singles}
    order = [r.effect for r in result.singles]
    fitted_vs_true: dict[str, dict[str, list[float | None]]] = {}
    for e in in_set if case.foreign is None else ():
        fitted = result.selected_params.get(e) or singles[e].params
        fitted_vs_true[e] = {
            k: [v, fitted.get(k)] for k, v in case.params[e].items() if k in fitted
        }
    return {
        "rank_of_true": {e: order.index(e) + 1 for e in in_set},
        "single_shrink_of_true": {e: round(singles[e].shrink, 4) for e in in_set},
        "fitted_vs_true": fitted_vs_true,
    }


def _gap_fields(result: WhichResult) -> dict[str, Any]:
    """The held-out gap before and after, the residual and the flags."""
    before, after = result.gap_before, result.gap_after
    return {
        "gap_before": round(before, 4),
        "gap_after": round(after, 4),
        "gap_floor": round(result.gap_floor, 4),
        "shrink": round(1 - after / before, 4) if before else 0.0,
        "unexplained": round(result.unexplained, 4),
        "residual_flagged": result.residual_flagged,
        "depth_split_first": result.stability.named_first if result.stability else None,
        "unstable": result.unstable,
        "flagged": result.flagged,
    }


def verdict(case: Case, row: dict[str, Any]) -> dict[str, Any]:
    """A single plant passes when named first; a double when both are selected; a lens blur
    (or blur + spread) when each required effect is selected or found confusable with a
    selected one; an out-of-catalogue plant when it is not blamed with high confidence (a
    selection and no flag)."""
    if case.kind == "single":
        expected = SHOWN_AS.get(case.planted[0], case.planted[0])
        return {"expected": expected, "passed": row["top1"] == expected}
    if case.kind == "double":
        return {"passed": all(e in row["selected"] for e in case.planted)}
    if case.kind == "named_or_confusable":
        accounted = set(row["selected"]) | {e for c in row["confusable"].values() for e in c}
        missing = [e for e in case.required if e not in accounted]
        return {"expected": " + ".join(case.required), "missing": missing, "passed": not missing}
    blamed = bool(row["selected"]) and not row["flagged"]
    return {"blamed_with_high_confidence": blamed, "passed": not blamed}


def validate_diagnosis(
    out: Path,
    quick: bool = False,
    n_pairs: int | None = None,
    seed: int = 0,
    size: int = 64,
    chars: tuple[str, ...] = CHARACTERS,
    progress: bool = True,
    suites: tuple[str, ...] = ("own",),
) -> dict[str, Any]:
    """Run every case, write ``validation.json`` and ``validation.md`` into ``out``."""
    start = time.perf_counter()
    n = n_pairs or (120 if quick else 200)
    bank = build_bank(chars, BrailleSpec())
    cases = make_cases(quick, seed, suites)
    rows = []
    for i, case in enumerate(tqdm(cases, desc="validate-diagnosis", disable=not progress)):
        rows.append(run_case(case, bank, n, seed, size, i))
    summary = summarise([r for r in rows if r["suite"] == suites[0]])
    summary["suites"] = {s: summarise([r for r in rows if r["suite"] == s]) for s in suites}
    if "foreign" in suites and not shared_real_available():
        summary["skipped"] = "foreign polycalib shading: ../shared/real is not at hand"
    summary.update(
        quick=quick, n_pairs=n, seed=seed, size=size, seconds=round(time.perf_counter() - start, 1)
    )
    write_report(Path(out), summary, rows)
    return {"summary": summary, "cases": rows}


def run_command(ns: argparse.Namespace) -> int:
    """``validate-diagnosis``: run the suites and print each one's summary line."""
    suites = SUITES if ns.suite == "both" else (ns.suite,)
    report = validate_diagnosis(
        Path(ns.out),
        ns.quick,
        ns.pairs,
        ns.seed,
        ns.size,
        progress=not ns.no_progress,
        suites=suites,
    )
    for name, s in report["summary"]["suites"].items():
        print(
            f"{name} suite: top-1 identification {s['top1_hits']}/{s['n_single']} single plants"
            f" ({100 * s['top1_accuracy']:.1f}%), mean rank of the true effect"
            f" {s['mean_rank_of_true']:.2f}; two-effect plants both found"
            f" {s['doubles_both_found']}/{s['n_double']}; out-of-catalogue flagged"
            f" {s['out_flagged']}/{s['n_out']}, blamed with high confidence"
            f" {s['out_blamed_high_confidence']}; lens blur and blur + spread named or found"
            f" confusable {s['told_apart']}/{s['n_told_apart']}"
        )
    print(f"{report['summary']['seconds']:.0f} s")
    print(f"wrote {Path(ns.out) / 'validation.json'} and validation.md")
    return 0
