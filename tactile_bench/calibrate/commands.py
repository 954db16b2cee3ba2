"""Subcommand ``calibrate``: a surrogate profile of the user's own sensor from paired frames.

The parser is built without importing torch (``--help`` answers at once); the command
imports its machinery when it runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from tactile_bench.diagnose.commands import KEEP_OMP_WAIT_POLICY

DEFAULT_HOLDOUT = 0.5  # run.DEFAULT_HOLDOUT (kept equal by tests/test_calibrate.py)


def _cmd_calibrate(ns: argparse.Namespace) -> int:
    from tactile_bench.calibrate.run import calibrate_pairs, check_holdout, check_out_dir
    from tactile_bench.diagnose.paired import detect_layout, load_paired

    check_holdout(ns.holdout, ns.curve)  # before reading any image
    check_out_dir(ns.out, ns.overwrite)
    _, base = detect_layout(ns.paired_dir)
    data = load_paired(ns.paired_dir, size=ns.size, render_missing_sim=True)
    result = calibrate_pairs(
        data,
        ns.out,
        holdout=ns.holdout,
        seed=ns.seed,
        curve=ns.curve,
        progress=not ns.no_progress,
        overwrite=ns.overwrite,
        source=str(Path(base).resolve()),
    )
    print("\n".join(summary_lines(result)))
    return 0


def summary_lines(result: dict[str, Any]) -> list[str]:
    """What ``calibrate`` prints: the selection, the held-out before / after, the files."""
    from tactile_bench.calibrate.curve import mean_of

    out = Path(result["profile"]["path"]).parent
    lines = [
        f"calibrated on {result['n_fit']} of {result['n_pairs']} pairs in "
        f"{result['timing_s']['total']:.1f} s; selected: "
        f"{', '.join(result['selected']) or 'nothing'}; background {result['background_k']} "
        "cosine terms"
    ]
    score = result["heldout"]
    if score is None:
        lines.append(result["heldout_note"])
    else:
        sim, prof = score["sim"], score["profile"]
        lines.append(
            f"held-out ({result['n_heldout']} pairs) contact MSE: plain sim "
            f"{mean_of(sim['contact_mse']):.2f} -> profile {mean_of(prof['contact_mse']):.2f}; "
            f"MSE {mean_of(sim['mse']):.2f} -> {mean_of(prof['mse']):.2f}"
        )
    files = ["profile.yaml", "calibration.json", "calibration.md"]
    files += ["curve.png"] if result["curve"] else []
    lines.append(f"wrote {', '.join(str(out / f) for f in files)}")
    lines.append(f"use it: --profile {result['profile']['path']}")
    return lines


def register(subparsers: Any) -> None:
    """Add ``calibrate``."""
    cal = subparsers.add_parser(
        "calibrate",
        help="fit a surrogate profile of your own sensor to paired (depth, real) frames",
        description="Splits the pairs into a fit half and a held-out half, fits on the fit "
        "half the no-contact field, the effects the gap diagnosis selects, the optical "
        "response and the camera noise, writes DIR/profile.yaml and scores it on the "
        "held-out half (calibration.json, calibration.md).",
    )
    cal.add_argument(
        "paired_dir",
        metavar="PAIRS",
        help="paired layout: depth/, real/, background.png, optional sim/ and gel.json",
    )
    cal.add_argument("--out", required=True, metavar="DIR", help="folder to write")
    cal.add_argument(
        "--holdout",
        type=float,
        default=DEFAULT_HOLDOUT,
        metavar="F",
        help=f"share of pairs held out to score the profile (default {DEFAULT_HOLDOUT:g}; "
        "0 fits on every pair and reports no held-out figures)",
    )
    cal.add_argument(
        "--curve",
        action="store_true",
        help="also calibrate on 4, 8, 16, ... of the fit pairs: curve.png",
    )
    cal.add_argument(
        "--size",
        type=int,
        metavar="S",
        help="resize every frame to S x S (default: min(64, shortest side), as diagnose)",
    )
    cal.add_argument("--seed", type=int, default=0)
    cal.add_argument("--overwrite", action="store_true", help="replace a non-empty DIR")
    cal.add_argument("--no-progress", action="store_true")
    cal.set_defaults(func=_cmd_calibrate, omp_wait_policy=KEEP_OMP_WAIT_POLICY)
