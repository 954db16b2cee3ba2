"""The whole diagnosis: where the gap lies, which effect causes it, how far it shrinks.

``diagnose`` splits the pairs into a fit half and a held-out half (stratified by label), so
every effect's parameters are fitted on one and its shrink measured on the other; then it
writes ``report.json`` and ``report.html``. It reads only the paired data.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.diagnose import breakdown
from tactile_bench.diagnose.breakdown import breakdown as span_breakdown
from tactile_bench.diagnose.paired import DiagnosisPairs, data_hash
from tactile_bench.diagnose.report import jsonable, write_report
from tactile_bench.diagnose.result import Diagnosis, Sample, Split
from tactile_bench.diagnose.shrink import HowFar, how_far
from tactile_bench.diagnose.simulate import apply_effects
from tactile_bench.diagnose.where import WhereResult, analyse_where
from tactile_bench.diagnose.which import WhichResult, explain_gap
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_write_json
from tactile_bench.sensor.timing import SpanTimer, timed_span

log = logging.getLogger("tactile_bench")
MIN_PAIRS = 4
N_SAMPLES = 6


def stratified_split(
    labels: Sequence[str], fit_fraction: float = 0.5, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor]:
    """(fit, held-out) sorted index tensors; each label split in ``fit_fraction``, seeded.

    A label's pairs go round(n * fraction) to the fit split; over all labels both splits
    get at least one pair.
    """
    if not 0 < fit_fraction < 1:
        raise TactileBenchError(f"fit_fraction must be in (0, 1), not {fit_fraction}")
    n = len(labels)
    if n < MIN_PAIRS:
        raise TactileBenchError(f"the diagnosis needs at least {MIN_PAIRS} pairs, got {n}")
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(label, []).append(i)
    fit, held = [], []
    carry = 0.0  # spreads the rounding of small groups so the overall fraction holds
    for label in sorted(groups):
        members = rng.permutation(groups[label])
        want = len(members) * fit_fraction + carry
        k = int(np.floor(want + 0.5))
        k = min(max(k, 0), len(members))
        carry = want - k
        fit += members[:k].tolist()
        held += members[k:].tolist()
    if not fit or not held:  # tiny sets: move one pair over
        src, dst = (fit, held) if not held else (held, fit)
        dst.append(src.pop())
    return torch.tensor(sorted(fit)), torch.tensor(sorted(held))


def pick_samples(
    data: DiagnosisPairs, held: torch.Tensor, k: int = N_SAMPLES, seed: int = 0
) -> list[int]:
    """``k`` held-out pairs for the before/after figure, as many labels as possible."""
    rng = np.random.default_rng(seed + 1)
    order = rng.permutation(held.numpy())
    picks, seen = [], set()
    for i in order:  # first one pair per label, then fill up
        if data.labels[i] not in seen:
            picks.append(int(i))
            seen.add(data.labels[i])
        if len(picks) == k:
            break
    for i in order:
        if len(picks) == k:
            break
        if int(i) not in picks:
            picks.append(int(i))
    return sorted(picks)


def check_candidates(names: Sequence[str] | None, key: str = "--candidates") -> None:
    """Unknown effect names are an error before any work (names only: no parameter values)."""
    if names is None:
        return
    from tactile_bench.effects import EFFECTS

    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise TactileBenchError(f"{key}: unknown effect(s) {unknown}; known: {', '.join(EFFECTS)}")
    if not names:
        raise TactileBenchError(f"{key}: give at least one candidate effect")


def selected_effects(which: WhichResult) -> dict[str, dict[str, float]]:
    """The selected effects' parameters: the final (e.g. jointly refitted) set when the
    "which" step reports one, else each ranking row's own fit."""
    if which.selected_params:
        return {name: dict(params) for name, params in which.selected_params.items()}
    return {fit.effect: dict(fit.params) for fit in which.ranking}


@dataclass(frozen=True)
class Steps:
    """The "which" and "how far" steps and the renderer of fitted effects: a seam where a
    test puts stand-ins."""

    explain_gap: Callable[..., WhichResult] = explain_gap
    how_far: Callable[..., HowFar] = how_far
    apply_effects: Callable[..., torch.Tensor] = apply_effects


def _where_before_after(
    held: DiagnosisPairs, after: torch.Tensor
) -> tuple[WhereResult, WhereResult]:
    """The "where" analysis of the held-out pairs with plain sim, then with ``after``."""
    held_after = DiagnosisPairs(
        held.depth, after, held.real, held.background, None, held.labels, held.names
    )
    return analyse_where(held), analyse_where(held_after)


def _sample_images(
    data: DiagnosisPairs,
    samples_idx: list[int],
    effects: dict[str, dict[str, float]],
    seed: int,
    fit_idx: torch.Tensor,
    steps: Steps,
) -> dict[str, torch.Tensor]:
    """The before/after figure's pairs: sim, real, and sim + the selected effects."""
    after = data.sim[samples_idx]
    if effects:
        after = steps.apply_effects(data, effects, torch.tensor(samples_idx), seed, fit_idx)
    return {"sim": data.sim[samples_idx], "real": data.real[samples_idx], "after": after}


def diagnose(
    data: DiagnosisPairs,
    out_dir: str | Path,
    downstream: bool = True,
    candidates: Sequence[str] | None = None,
    seed: int = 0,
    fit_fraction: float = 0.5,
    progress: bool = True,
    source: dict[str, Any] | None = None,
    steps: Steps = Steps(),
) -> Diagnosis:
    """Run the diagnosis on ``data`` and write ``out_dir/report.{json,html}``.

    ``source`` describes the input for the report (``root``, ``layout``); the content hash
    of the pairs is added here. ``timing_s`` holds each step's seconds and, under
    ``breakdown``, the calls and seconds of every timed span (``diagnose.breakdown``).
    """
    timing: dict[str, Any] = {}
    start = time.perf_counter()
    with SpanTimer() as timer, timed_span(breakdown.DIAGNOSE):
        result, sample_images, row_labels = _run_steps(
            data, downstream, candidates, seed, fit_fraction, progress, source, steps, timing
        )
        # the HTML's timing table: every span so far (the report's own come after it)
        timing["breakdown"] = span_breakdown(timer)
        t = time.perf_counter()
        with timed_span(breakdown.REPORT):
            paths = write_report(out_dir, result, sample_images, row_labels)
        timing["report"] = time.perf_counter() - t
    timing["total"] = time.perf_counter() - start
    timing["breakdown"] = span_breakdown(timer)
    atomic_write_json(paths["json"], jsonable(result.to_dict()))  # now with the report's time
    return result


def _run_steps(
    data: DiagnosisPairs,
    downstream: bool,
    candidates: Sequence[str] | None,
    seed: int,
    fit_fraction: float,
    progress: bool,
    source: dict[str, Any] | None,
    steps: Steps,
    timing: dict[str, Any],
) -> tuple[Diagnosis, dict[str, torch.Tensor], list[str]]:
    """Where, which, how far and the samples: the result (its ``timing_s`` is ``timing``,
    each step's seconds added here), the before/after images and their row labels."""
    fit_idx, held_idx = stratified_split(data.labels, fit_fraction, seed)

    t = time.perf_counter()
    with timed_span(breakdown.WHERE):
        where = analyse_where(data)
    timing["where"] = time.perf_counter() - t
    log.info("where: %.1f s; mean squared error %.2f", timing["where"], where.summary["mse"])

    t = time.perf_counter()
    with timed_span(breakdown.WHICH):
        which = steps.explain_gap(
            data, fit_idx, held_idx, candidates=candidates, seed=seed, progress=progress
        )
    timing["which"] = time.perf_counter() - t
    effects = selected_effects(which)
    log.info("which: %.1f s; selected %s", timing["which"], list(effects) or "nothing")

    t = time.perf_counter()
    with timed_span(breakdown.HOW_FAR):
        far = steps.how_far(
            data, fit_idx, held_idx, effects, downstream=downstream, seed=seed, progress=progress
        )
    timing["how_far"] = time.perf_counter() - t

    t = time.perf_counter()
    with timed_span(breakdown.SAMPLES):
        held_where = None
        if effects:
            after = steps.apply_effects(data, effects, held_idx, seed, fit_idx)
            with timed_span(breakdown.WHERE):
                held_where = _where_before_after(data.subset(held_idx), after)
        samples_idx = pick_samples(data, held_idx, seed=seed)
        sample_images = _sample_images(data, samples_idx, effects, seed, fit_idx, steps)
    result = Diagnosis(
        n_pairs=len(data),
        size=data.size,
        input={**(source or {}), "hash": data_hash(data)},
        split=Split(len(fit_idx), len(held_idx), fit_fraction, seed),
        where=where,
        where_held=held_where,
        which=which,
        how_far=far,
        samples=[Sample(i, data.labels[i], data.names[i]) for i in samples_idx],
        timing_s=timing,
    )
    timing["samples"] = time.perf_counter() - t
    row_labels = [f"{data.labels[i] or '-'} / {data.names[i]}" for i in samples_idx]
    return result, sample_images, row_labels
