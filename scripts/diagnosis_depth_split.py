"""The selection on a random split against a split by press depth, per validation case.

    python scripts/diagnosis_depth_split.py "defocus_blur (not a candidate)" defocus_blur ...

For each named case of ``validate-diagnosis`` (own or foreign suite, the same data seeds),
runs the selection three times with the depth-split check off: on the suite's random
fit/held-out split, with the shallowest half of the presses fitted and the deepest held out,
and the reverse. It prints what each names, the non-lookup parameters it fits and the
unexplained share. An effect of the sensor should name itself on all three; this is the
experiment behind ``tactile_bench.diagnose.stability``.
"""

from __future__ import annotations

import argparse
import json
import time

from tactile_bench.diagnose import validate as V
from tactile_bench.diagnose.candidates import DEFAULT_CANDIDATES
from tactile_bench.diagnose.stability import depth_halves
from tactile_bench.diagnose.which import explain_gap


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+", help="case names as validate-diagnosis prints them")
    parser.add_argument("--pairs", type=int, default=200)
    args = parser.parse_args()
    seed, size = 0, 64
    cases = V.make_cases(False, seed, ("own", "foreign"))
    bank = V.build_bank(V.CHARACTERS, V.BrailleSpec())
    for name in args.cases:
        index = next(i for i, c in enumerate(cases) if c.name == name)
        case = cases[index]
        data, random_fit, random_held = V.case_pairs(case, bank, args.pairs, seed, size, index)
        shallow, deep = depth_halves(data.depth, n_max=args.pairs)
        splits = {
            "random": (random_fit, random_held),
            "shallow->deep": (shallow, deep),
            "deep->shallow": (deep, shallow),
        }
        candidates = [c for c in DEFAULT_CANDIDATES if c not in case.removed]
        for label, (fit_idx, held_idx) in splits.items():
            start = time.perf_counter()
            result = explain_gap(
                data, fit_idx, held_idx, candidates, seed, progress=False, stability=False
            )
            params = {
                effect: {k: round(v, 3) for k, v in p.items()}
                for effect, p in result.selected_params.items()
                if effect != "optical_response"  # a lookup table, not a few numbers
            }
            row = {
                "case": name,
                "split": label,
                "selected": [(r.effect, round(r.shrink, 3)) for r in result.ranking],
                "unexplained": round(result.unexplained, 3),
                "params": params,
                "s": round(time.perf_counter() - start),
            }
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
