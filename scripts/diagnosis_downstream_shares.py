"""Does an effect's share of the image gap predict its share of the accuracy gap?

    python scripts/diagnosis_downstream_shares.py PAIRS_DIR REPORT_DIR [--seeds N]

Reads a diagnosis (``diagnose PAIRS_DIR --out REPORT_DIR``, downstream classifiers on) of two
selected effects and trains the downstream classifier on the fit split's sim with no
effect, with each selected effect alone (its single fit, as the diagnosis's Shapley shares
use it) and with both (the selection's joint fit), all through one path: the candidate
simulator's images over its own no-contact frame (``shrink.accuracy_with_each``), so every
coalition differs from the empty one only by its effects. Prints, for each effect, its
Shapley share of the held-out image gap beside its Shapley share of the accuracy gained,
per classifier seed and their mean. The report's own plain-sim accuracy (the exported sim
images, whose renderer and noise differ from the candidate simulator's) is printed for
reference, not used.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import torch

from tactile_bench.diagnose.paired import load_paired
from tactile_bench.diagnose.run import stratified_split
from tactile_bench.diagnose.shapley import shapley_values
from tactile_bench.diagnose.shrink import accuracy_with_each


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs")
    parser.add_argument("report")
    parser.add_argument("--seeds", type=int, default=3, help="classifier seeds (default 3)")
    ns = parser.parse_args()
    report = json.loads((Path(ns.report) / "report.json").read_text())
    selected = report["which"]["selected_params"]
    if len(selected) != 2:
        raise SystemExit(f"{ns.report}: {len(selected)} effects selected; this check takes 2")
    data = load_paired(ns.pairs, size=report["size"])
    split = report["split"]
    fit_idx, held_idx = stratified_split(data.labels, split["fit_fraction"], split["seed"])
    singles = {r["effect"]: r["params"] for r in report["singles"]}
    names = sorted(selected)
    coalitions = {"none": {}, **{n: {n: singles[n]} for n in names}, "both": selected}
    image = {s["effect"]: s for s in report["shapley"]}
    down = report["downstream"]
    print(
        "| classifier seed | sim alone | "
        + " | ".join(f"sim + {n} alone" for n in names)
        + " | sim + both | "
        + " | ".join(f"{n} gained (Shapley), share" for n in names)
        + " |"
    )
    print("| --- " * (3 + 2 * len(names)) + "|")
    shares: dict[str, list[float]] = {n: [] for n in names}
    for k in range(ns.seeds):
        seed = split["seed"] + k
        acc = accuracy_with_each(data, fit_idx, held_idx, coalitions, seed)
        values = {frozenset(): acc["none"], frozenset(names): acc["both"]}
        values |= {frozenset([n]): acc[n] for n in names}
        # Shapley of the accuracy *gained* (the negative of a gap removed)
        gained = shapley_values(
            names, {c: torch.tensor(-v, dtype=torch.float64) for c, v in values.items()}
        )
        total = acc["both"] - acc["none"]
        cells = []
        for n in names:
            share = float(gained[n]) / total if total else float("nan")
            shares[n].append(share)
            cells.append(f"{float(gained[n]):+.3f}, {share:.2f}")
        print(
            f"| {seed} | {acc['none']:.3f} | "
            + " | ".join(f"{acc[n]:.3f}" for n in names)
            + f" | {acc['both']:.3f} | "
            + " | ".join(cells)
            + " |"
        )
    for n in names:
        s = image[n]
        per_seed = ", ".join(f"{v:.2f}" for v in shares[n])
        explained = sum(image[m]["share"] for m in names)
        print(
            f"{n}: image-gap Shapley share {s['share']:.3f} [{s['ci_low']:.3f}, "
            f"{s['ci_high']:.3f}] ({s['share'] / explained:.2f} of the explained gap); "
            f"share of the accuracy gained, mean over {ns.seeds} seeds "
            f"{statistics.mean(shares[n]):.2f} (per seed {per_seed})"
        )
    print(
        f"report (seed {split['seed']}): plain sim (exported images) "
        f"{down['plain_sim_accuracy']:.3f}, sim + both {down['sim_plus_effects_accuracy']:.3f}, "
        f"real {down['real_accuracy']:.3f} ({down['n_test']} held-out real, "
        f"{down['classes']} classes)"
    )


if __name__ == "__main__":
    main()
