"""Does an effect's share of the image gap predict its share of the accuracy gap?

    python scripts/diagnosis_downstream_shares.py PAIRS_DIR REPORT_DIR

Reads a diagnosis (``diagnose PAIRS_DIR --out REPORT_DIR``, downstream classifiers on) of two
selected effects, trains the downstream classifier on the fit split's sim + each selected
effect alone (its single fit, as the diagnosis's Shapley shares use it), and prints, for
each effect, its Shapley share of the held-out image gap beside its Shapley share of the
accuracy gap (plain sim -> sim + both effects; real-trained accuracy for scale). The plain,
both-effects and real accuracies are the report's own; the same split, seed and training.
"""

from __future__ import annotations

import argparse
import json
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
    ns = parser.parse_args()
    report = json.loads((Path(ns.report) / "report.json").read_text())
    selected = report["which"]["selected_params"]
    if len(selected) != 2:
        raise SystemExit(f"{ns.report}: {len(selected)} effects selected; this check takes 2")
    data = load_paired(ns.pairs, size=report["size"])
    split = report["split"]
    fit_idx, held_idx = stratified_split(data.labels, split["fit_fraction"], split["seed"])
    singles = {r["effect"]: r["params"] for r in report["singles"]}
    alone = {name: {name: singles[name]} for name in selected}
    accuracy = accuracy_with_each(data, fit_idx, held_idx, alone, split["seed"])
    down = report["downstream"]
    names = sorted(selected)
    acc = {
        frozenset(): down["plain_sim_accuracy"],
        frozenset(names): down["sim_plus_effects_accuracy"],
    }
    acc |= {frozenset([n]): accuracy[n] for n in names}
    # Shapley of the accuracy *gained* (the negative of a gap removed)
    gained = shapley_values(
        names, {c: torch.tensor(-v, dtype=torch.float64) for c, v in acc.items()}
    )
    image = {s["effect"]: s for s in report["shapley"]}
    gap = down["real_accuracy"] - down["plain_sim_accuracy"]
    print(
        "| effect | image-gap Shapley share [95% CI] | accuracy alone | accuracy gained "
        "(Shapley) | share of the accuracy gap (plain -> real) |"
    )
    print("| --- | --- | --- | --- | --- |")
    for n in names:
        s = image[n]
        print(
            f"| {n} | {s['share']:.3f} [{s['ci_low']:.3f}, {s['ci_high']:.3f}] | {accuracy[n]:.3f} "
            f"| {float(gained[n]):+.3f} | {float(gained[n]) / gap:.2f} |"
        )
    print(
        f"plain sim {down['plain_sim_accuracy']:.3f}, sim + both "
        f"{down['sim_plus_effects_accuracy']:.3f}, real {down['real_accuracy']:.3f} "
        f"({down['n_test']} held-out real, {down['classes']} classes)"
    )


if __name__ == "__main__":
    main()
