"""Subcommands ``diagnose`` (the gap diagnosis), ``export-pairs`` (data in its layout) and
``validate-diagnosis`` (the diagnosis on planted effects).

The parsers are built without importing torch (``--help`` answers at once); each command
imports its machinery when it runs.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tactile_bench.errors import TactileBenchError

if TYPE_CHECKING:  # the parsers load without torch: the types are for reading only
    from tactile_bench.diagnose.no_contact import FrameReading
    from tactile_bench.diagnose.result import Diagnosis
    from tactile_bench.diagnose.shrink import HowFar
    from tactile_bench.diagnose.which import WhichResult

# ------------------------------------------------------------------------------ diagnose
#: a mean squared difference real - sim below the variance of 8-bit rounding (1/12 of a
#: level squared) is no gap: any effect "explaining" it would be fitted to noise
NO_GAP_MSE = 1.0 / 12.0


#: the diagnosis runs thousands of small tensor ops: OpenMP's threads sleeping between them
#: (the CLI's PASSIVE wait policy) slow it down, so it keeps the environment's policy (None:
#: leave it alone; timings in docs/results/gap_validation.md)
KEEP_OMP_WAIT_POLICY = None


def _g(value: Any) -> str:
    """A number to 4 significant digits; anything else as it is."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    return f"{value:.4g}"


def _first_lines(which: WhichResult) -> list[str]:
    """The background correction and any confusable set: what a reader must see first."""
    bg = which.background
    if bg:
        lines = [
            f"background: the measured no-contact frame in place of the sim's removes "
            f"{bg.shrink:.3f} [{bg.ci_low:.3f}, {bg.ci_high:.3f}] of the gap "
            "(data, nothing fitted); effects are ranked on what is left"
        ]
    else:
        lines = [f"background: {which.background_note or 'no correction'}"]
    optics = which.sim_optics
    if optics:
        lines.append(
            f"sim optics for geometry effects: {optics['model']} (MSE on held-in sim images: "
            f"built-in {optics['builtin_mse']}, fitted lookup {optics['lookup_mse']})"
        )
    for fit in which.ranking:
        if fit.confusable_with:
            lines.append(
                f"confusable: {fit.effect} ~ {', '.join(fit.confusable_with)} "
                "(the data at hand cannot tell them apart)"
            )
    return lines


def _ranking_lines(which: WhichResult) -> list[str]:
    """The greedy selection, row by row, and what it set aside."""
    lines = ["which effects explain it (greedy order; shrink of the held-out gap, 95% CI):"]
    for fit in which.ranking:
        lines.append(
            f"  {fit.effect:<20} shrink {fit.shrink:.3f} [{fit.ci_low:.3f}, {fit.ci_high:.3f}]"
            f"  gap {fit.gap_before:.4g} -> {fit.gap_after:.4g}"
        )
        if fit.no_contact is not None:
            lines.append(f"    {frame_line(fit.no_contact)}")
        if fit.confusable_with:
            lines.append(
                f"    not told apart from: {', '.join(fit.confusable_with)} "
                f"(to separate them: {fit.separate_by})"
            )
    if not which.ranking:
        lines.append("  (no candidate effect shrinks the gap)")
    if which.shapley:
        lines.append(
            "  whatever the order (Shapley share of the held-out gap over every order of the "
            "selected effects, 95% CI):"
        )
        for s in sorted(which.shapley, key=lambda s: -s.share):
            lines.append(f"  {s.effect:<20} share  {s.share:.3f} [{s.ci_low:.3f}, {s.ci_high:.3f}]")
    if which.set_aside_as_denoising:
        lines.append(
            f"  set aside: {', '.join(which.set_aside_as_denoising)} (removes only the sim's "
            "own noise, which the real frames have less of)"
        )
    return lines


def frame_line(reading: FrameReading) -> str:
    """What the no-contact frame says of a selected lens effect, in one line."""
    if not reading.decides and math.isnan(reading.ci_low):
        return f"no-contact frame: {reading.status}"
    return (
        f"no-contact frame: {reading.status} (texture gap {reading.gap_before:.3g} -> "
        f"{reading.gap_after:.3g} grey level^2 with it; removed 95% CI "
        f"[{reading.ci_low:.3g}, {reading.ci_high:.3g}])"
    )


def _residual_lines(which: WhichResult) -> list[str]:
    """The unexplained share, the noise it is counted above, and any flag."""
    from tactile_bench.diagnose.stability import warning as stability_warning

    lines = [f"unexplained share of the held-out gap: {which.unexplained:.3f}"]
    if which.noise:
        sides = ", ".join(f"{k.replace('_', ' ')} {max(v):.2g}" for k, v in which.noise.items())
        lines.append(f"  counted above the pairs' own noise (std, grey levels: {sides})")
    if which.residual_flagged:
        lines.append("  note: a large residual remains that no candidate explains")
    unstable = stability_warning(which.stability)
    if unstable:
        lines.append(f"  note: {unstable}")
    return lines


def _how_far_lines(far: HowFar) -> list[str]:
    """Pixel, distribution and downstream measures before and after the effects."""
    from tactile_bench.diagnose.shrink import KidScores, Skipped

    b, a = far.pixel_before, far.pixel_after
    lines = [
        "how far it shrinks (held-out): "
        + ", ".join(f"{k} {_g(b[k])} -> {_g(a[k])}" for k in b if k in a)
    ]
    if isinstance(far.distribution, KidScores):
        kid = far.distribution
        lines.append(f"  KID {_g(kid.kid_before)} -> {_g(kid.kid_after)}")
    down = far.downstream
    if isinstance(down, Skipped):
        lines.append(f"  downstream: skipped ({down.reason})")
    else:
        lines.append(
            "  downstream accuracy on held-out real: "
            + ", ".join(f"{k} {_g(v)}" for k, v in down.accuracies.items())
        )
    return lines


def summary_lines(result: Diagnosis) -> list[str]:
    """The text summary ``diagnose`` prints."""
    where = result.where.summary
    lines = [
        f"diagnosed {result.n_pairs} pairs ({result.split.n_fit} fit / {result.split.n_held} "
        f"held-out) in {result.timing_s['total']:.1f} s; mean squared error real - sim "
        f"{where['mse']:.2f}"
    ]
    lines += _first_lines(result.which)
    lines.append("where the gap lies (top part of each axis, share of the squared error):")
    for row in where["dominant"]:
        extra = f", intensity {row['intensity']:.2f}" if row.get("intensity") is not None else ""
        lines.append(f"  {row['axis']:<12} {row['part']:<24} {100 * row['share']:5.1f}%{extra}")
    return (
        lines
        + _ranking_lines(result.which)
        + _residual_lines(result.which)
        + _how_far_lines(result.how_far)
    )


def _cmd_diagnose(ns: argparse.Namespace) -> int:
    from tactile_bench.diagnose.paired import detect_layout, load_paired
    from tactile_bench.diagnose.run import check_candidates, diagnose, stratified_split
    from tactile_bench.diagnose.workers import fit_workers, parse_workers

    workers = parse_workers(ns.workers)
    check_candidates(ns.candidates)
    layout, base = detect_layout(ns.paired_dir)
    data = load_paired(ns.paired_dir, size=ns.size)
    if not bool((data.depth > 0).any()):  # no contact anywhere: no effect can be measured
        raise TactileBenchError(
            f"{ns.paired_dir}: no pair has any contact (depth 0 everywhere): nothing to diagnose"
        )
    gap = float(((data.real - data.sim) ** 2).mean())
    if gap < NO_GAP_MSE:  # nothing to explain: say so, select nothing
        same = "equal" if gap == 0 else "are within 8-bit rounding of"
        raise TactileBenchError(
            f"{ns.paired_dir}: the real images {same} the sim images (mean squared "
            f"difference {gap:.3g}, below {NO_GAP_MSE:.3g}): there is no sim-to-real gap to "
            "diagnose"
        )
    if ns.max_pairs is not None and len(data) > ns.max_pairs:
        keep, _ = stratified_split(data.labels, ns.max_pairs / len(data), ns.seed)
        data = data.subset(keep)
    with fit_workers(workers):
        report = diagnose(
            data,
            ns.out,
            downstream=not ns.no_downstream,
            candidates=ns.candidates,
            seed=ns.seed,
            fit_fraction=ns.fit_fraction,
            progress=not ns.no_progress,
            source={"root": str(Path(base).resolve()), "layout": layout},
        )
    print("\n".join(summary_lines(report)))
    if ns.timing:
        from tactile_bench.diagnose.breakdown import breakdown_lines

        print("where the time went (seconds exclude the spans inside; most first):")
        print("\n".join(breakdown_lines(report.timing_s["breakdown"])))
    out = Path(ns.out)
    print(f"wrote {out / 'report.json'} and {out / 'report.html'}")
    return 0


# ------------------------------------------------------------------------------ export-pairs
def find_braille_set(source: str | Path, set_name: str) -> tuple[Path, tuple[str, ...] | None]:
    """The ``<set>.npz`` of a braille_data stage dir, a run dir holding one, or the file itself."""
    from tactile_bench.diagnose.paired import braille_stage_chars

    path = Path(source)
    if path.is_file():
        return path, braille_stage_chars(path.parent)
    if not path.is_dir():
        raise TactileBenchError(f"{path}: no such file or folder")
    if (path / f"{set_name}.npz").is_file():
        return path / f"{set_name}.npz", braille_stage_chars(path)
    found = sorted(p for p in path.glob(f"*/{set_name}.npz") if (p.parent / "_done.json").exists())
    if not found:
        raise TactileBenchError(
            f"{path}: no braille set {set_name!r} (expected {set_name}.npz in a braille_data stage)"
        )
    if len(found) > 1:
        listed = ", ".join(str(p.parent.name) for p in found)
        raise TactileBenchError(f"{path}: several stages hold {set_name}.npz ({listed}); pass one")
    return found[0], braille_stage_chars(found[0].parent)


def _generate(ns: argparse.Namespace, chars: tuple[str, ...]) -> Any:
    return generate_pairs(
        ns.generate,
        chars,
        profile=ns.profile,
        size=ns.size,
        seed=ns.seed,
        protocol=ns.protocol,
        noise_free_sim=ns.noise_free_sim,
        progress=not ns.no_progress,
    )


def generate_pairs(
    n: int,
    chars: tuple[str, ...],
    profile: str = "digit",
    size: int = 64,
    seed: int = 0,
    protocol: str = "classifier",
    noise_free_sim: bool = False,
    progress: bool = False,
) -> Any:
    """``n`` fresh braille pairs of ``chars`` as ``export-pairs --generate N`` renders them
    (a ``data.braille.BrailleSet``: sim, and the surrogate ``profile`` playing real), drawn
    from the ``protocol``'s contact grid, seeded."""
    import torch
    from tqdm.auto import tqdm

    from tactile_bench.data.braille import draw_disjoint, render_braille_set
    from tactile_bench.data.corpus import to_uint8
    from tactile_bench.geometry.braille import BrailleSpec
    from tactile_bench.geometry.contacts import classifier_protocol, finetune_test_protocol
    from tactile_bench.sensor.background import sim_background
    from tactile_bench.sensor.depth import GelSpec
    from tactile_bench.sensor.heightfield import build_bank
    from tactile_bench.sensor.optics import SimOptics
    from tactile_bench.sensor.surrogate import SurrogateDigit

    real = SurrogateDigit.from_profile(profile)
    gel = GelSpec(size=size)
    protocols = {"classifier": classifier_protocol, "finetune": finetune_test_protocol}
    if protocol not in protocols:
        raise TactileBenchError(f"protocol: {protocol!r} is not one of {', '.join(protocols)}")
    grid = protocols[protocol](chars)
    (idx,) = draw_disjoint(grid.labels, (n,), len(chars), seed)
    bank = build_bank(chars, BrailleSpec())
    optics = SimOptics(noise_std=0.0) if noise_free_sim else SimOptics()
    with tqdm(total=len(idx), desc="render pairs", unit="pair", disable=not progress) as bar:
        return render_braille_set(
            bank,
            grid.index(idx),
            gel,
            optics,
            to_uint8(sim_background(size)),
            real,
            to_uint8(real.background(gel.size)),
            torch.Generator().manual_seed(seed),
            torch.Generator().manual_seed(seed + 1),
            bar=bar,
        )


def _cmd_export_pairs(ns: argparse.Namespace) -> int:
    from tactile_bench.data.braille import BrailleSet
    from tactile_bench.diagnose.paired import from_braille_set, write_paired
    from tactile_bench.geometry.braille import CHARACTERS

    if ns.real_presses is not None:
        return _export_real_presses(ns)
    if (ns.source is None) == (ns.generate is None):
        raise TactileBenchError(
            "export-pairs: give a run/stage folder or .npz, --generate N or --real-presses SENSOR"
        )
    if ns.chars is not None:
        unknown = sorted(set(ns.chars) - set(CHARACTERS))
        if unknown or len(ns.chars) < 1:
            raise TactileBenchError(f"--chars: not braille characters of the paper: {unknown}")
    start = time.perf_counter()
    if ns.generate is not None:
        if ns.generate < 1:
            raise TactileBenchError("--generate: must be a positive number of pairs")
        chars = tuple(ns.chars or CHARACTERS)
        bset = _generate(ns, chars)
        what = f"fresh pairs of the {ns.protocol} grid (surrogate profile {ns.profile})"
    else:
        path, stage_chars = find_braille_set(ns.source, ns.set)
        chars = tuple(ns.chars or stage_chars or CHARACTERS)
        bset = BrailleSet.load(path)
        what = f"pairs of {path}"
    root = write_paired(ns.out, from_braille_set(bset, chars), overwrite=ns.overwrite)
    print(f"wrote {len(bset)} {what} to {root} in {time.perf_counter() - start:.1f} s")
    return 0


def _export_real_presses(ns: argparse.Namespace) -> int:
    from tactile_bench.diagnose.paired import write_paired
    from tactile_bench.real_presses import press_pairs

    if ns.source is not None or ns.generate is not None:
        raise TactileBenchError("export-pairs: --real-presses takes no source and no --generate")
    start = time.perf_counter()
    data = press_pairs(ns.real_presses, ns.size)
    root = write_paired(ns.out, data, overwrite=ns.overwrite)
    print(
        f"wrote {len(data)} real {ns.real_presses} presses (sim: our simulator on the real "
        f"no-contact frame) to {root} in {time.perf_counter() - start:.1f} s"
    )
    return 0


def _cmd_validate(ns: argparse.Namespace) -> int:
    # imported here, not at the top: diagnose.validate loads torch and the whole renderer
    from tactile_bench.diagnose.validate import run_command

    return run_command(ns)


# ------------------------------------------------------------------------------ parsers
#: ``validate-diagnosis --suite`` choices
VALIDATION_SUITES = ("own", "foreign", "both")


def register(subparsers: Any) -> None:
    """Add ``diagnose``, ``export-pairs`` and ``validate-diagnosis``."""
    _add_diagnose(subparsers)
    _add_export_pairs(subparsers)
    _add_validate(subparsers)


def _add_diagnose(subparsers: Any) -> None:
    """``diagnose PAIRED_DIR --out OUT_DIR``: where, which effect, how far."""
    diag = subparsers.add_parser(
        "diagnose",
        help="diagnose the sim-to-real gap of paired data: where, which effect, how far",
    )
    diag.add_argument(
        "paired_dir", metavar="PAIRED_DIR", help="paired layout or Tactile-Diffusion braille"
    )
    diag.add_argument(
        "--out", required=True, metavar="OUT_DIR", help="folder for report.json and report.html"
    )
    diag.add_argument("--no-downstream", action="store_true", help="skip the classifier part")
    diag.add_argument(
        "--candidates", nargs="+", metavar="EFFECT", help="candidate effects (default: all)"
    )
    diag.add_argument("--seed", type=int, default=0)
    diag.add_argument(
        "--max-pairs", type=int, metavar="N", help="use a stratified subset of this many pairs"
    )
    diag.add_argument("--fit-fraction", type=float, default=0.5, help="share of pairs for fitting")
    diag.add_argument(
        "--size",
        type=int,
        metavar="S",
        help="resize every frame to S x S (default: min(64, shortest side), the size the "
        "diagnosis is validated at; the Tactile-Diffusion layout: 64)",
    )
    diag.add_argument(
        "--timing",
        action="store_true",
        help="also print where the time went: calls and seconds of every timed span "
        "(always in report.json's timing_s.breakdown)",
    )
    diag.add_argument(
        "--workers",
        default="1",
        metavar="N",
        help="processes the diagnosis's fits run in side by side, one torch thread each "
        "(auto: one per core, at most 8; default 1: all in this process, which on 2 cores "
        "is as fast: docs/results/diagnosis_speed.md)",
    )
    diag.add_argument("--no-progress", action="store_true")
    diag.set_defaults(func=_cmd_diagnose, omp_wait_policy=KEEP_OMP_WAIT_POLICY)


def _add_export_pairs(subparsers: Any) -> None:
    """``export-pairs``: braille pairs (a run's, fresh ones, or real presses) as a paired layout."""
    exp = subparsers.add_parser(
        "export-pairs", help="write braille pairs in the diagnosis's paired layout"
    )
    exp.add_argument(
        "source",
        nargs="?",
        metavar="RUN_OR_STAGE_DIR_OR_NPZ",
        help="a run folder, a braille_data stage folder, or a set .npz",
    )
    exp.add_argument("--set", default="test", help="which set of a braille_data stage")
    exp.add_argument(
        "--out", required=True, metavar="DIR", help="folder to write (must not exist or be empty)"
    )
    exp.add_argument(
        "--generate", type=int, metavar="N", help="render this many fresh pairs instead"
    )
    exp.add_argument(
        "--protocol",
        choices=("classifier", "finetune"),
        default="classifier",
        help="--generate: contact grid; classifier = upright, yaw -25..25 deg, +-3 mm (396 a "
        "character; what the downstream classifiers learn from); finetune = yaw 0, +-45, "
        "+-90 deg, +-5 mm (180 a character; the paper's paired real set)",
    )
    exp.add_argument(
        "--real-presses",
        metavar="SENSOR",
        help="write the real ball presses of the taxim package (gelsight, gelsight-mini) "
        "instead: depth from the annotated sphere, sim from our simulator",
    )
    exp.add_argument("--profile", default="digit", help="surrogate profile playing 'real'")
    exp.add_argument("--chars", help="braille characters (default: the stage's, or all 27)")
    exp.add_argument("--size", type=int, default=64, help="image size for --generate")
    exp.add_argument("--seed", type=int, default=0, help="seed for --generate")
    exp.add_argument(
        "--noise-free-sim", action="store_true", help="--generate: sim without its noise"
    )
    exp.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    exp.add_argument("--no-progress", action="store_true")
    exp.set_defaults(func=_cmd_export_pairs)


def _add_validate(subparsers: Any) -> None:
    """``validate-diagnosis``: plant withheld effects and check what the diagnosis names."""
    val = subparsers.add_parser(
        "validate-diagnosis",
        help="plant withheld effects in surrogate-real data and check the gap diagnosis",
        description="Renders braille contacts twice with the surrogate (sim: no effect; real: "
        "planted effects at random parameters), diagnoses blind and checks the planted effect "
        "is named; writes validation.json and validation.md (diagnose.validate).",
    )
    val.add_argument("--out", default="runs/validate_diagnosis", help="output directory")
    val.add_argument("--quick", action="store_true", help="a few cases, fewer pairs (minutes)")
    val.add_argument(
        "--pairs", type=int, default=None, help="pairs per case (default 200, quick 120)"
    )
    val.add_argument("--seed", type=int, default=0)
    val.add_argument("--size", type=int, default=64, help="image size")
    val.add_argument(
        "--suite",
        # diagnose.validate.SUITES plus "both" (tests/test_cli_startup.py keeps them equal)
        choices=VALIDATION_SUITES,
        default="both",
        help="own: the project's renderer; foreign: an independent renderer (default both)",
    )
    val.add_argument("--no-progress", action="store_true")
    val.set_defaults(func=_cmd_validate, omp_wait_policy=KEEP_OMP_WAIT_POLICY)
