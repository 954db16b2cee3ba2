"""An image blur the catalogue lacks, on braille and on presses of several sizes (an A/B).

    python scripts/diagnosis_feature_scale.py {braille,spheres} [--withheld] [--pairs 200]

The own suite's ``defocus_blur (not a candidate)`` case is blamed on ``optical_response`` +
``elastic_spread`` with 1.8% of the gap unexplained. A blur's loss of contrast depends on a
feature's size; a slope-to-colour lookup's does not, so contacts that all have one feature
size (braille dots) cannot tell them apart, and presses of several sizes might. This
plants the same surrogate blur (the own suite's draw, sigma 0.883 mm) into braille contacts
or into spheres of radii 0.75, 1.5, 3 and 6 mm pressed 0.3-1 mm deep at random places
(nothing else changes), then diagnoses the pairs with every candidate (the control) or with
``defocus_blur`` withheld, and prints the selection and the unexplained share.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from tactile_bench.diagnose.candidates import DEFAULT_CANDIDATES
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.effects.kernels import area_pool
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit

PLANT = {"defocus_blur": {"sigma_mm": 0.8830999732017517}}  # the own suite's draw
RADII_MM = (0.75, 1.5, 3.0, 6.0)


def sphere_pairs(planted: dict, n: int, seed: int) -> DiagnosisPairs:
    """``n`` sphere presses rendered by the plain surrogate (sim) and with ``planted``."""
    gel = GelSpec(size=64)
    side = gel.size * gel.oversample
    rng = np.random.default_rng(seed)
    x = (np.arange(side) + 0.5) / side * gel.width_mm - gel.width_mm / 2
    y = (np.arange(side) + 0.5) / side * gel.height_mm - gel.height_mm / 2
    xx, yy = np.meshgrid(x, y)
    heights, labels = [], []
    for i in range(n):
        radius = RADII_MM[i % len(RADII_MM)]
        press = rng.uniform(0.3, min(1.0, 0.8 * radius))
        cx, cy = rng.uniform(-5, 5), rng.uniform(-8, 8)
        r2 = (xx - cx) ** 2 + (yy - cy) ** 2
        cap = np.where(r2 < radius**2, radius - np.sqrt(np.clip(radius**2 - r2, 0, None)), 9.0)
        heights.append(np.maximum(press - cap, -1.0))  # > 0: into the gel
        labels.append(f"r{radius:g}")
    height = torch.tensor(np.stack(heights)[:, None], dtype=torch.float32)
    sim_sensor, real_sensor = SurrogateDigit({}), SurrogateDigit(planted)
    sim = sim_sensor.render_surface(height, gel, torch.Generator().manual_seed(seed + 1))
    real = real_sensor.render_surface(height, gel, torch.Generator().manual_seed(seed + 2))
    return DiagnosisPairs(
        depth=area_pool(height.clamp(min=0), gel.oversample),  # as the camera's pixels
        sim=sim.round(),
        real=real.round(),
        background=real_sensor.background(gel).round(),
        sim_background=sim_sensor.background(gel).round(),
        labels=labels,
        names=[f"press_{i:04d}" for i in range(n)],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("contacts", choices=("braille", "spheres"))
    parser.add_argument("--withheld", action="store_true", help="defocus_blur not a candidate")
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=5)
    ns = parser.parse_args()
    if ns.contacts == "spheres":
        data = sphere_pairs(PLANT, ns.pairs, ns.seed)
    else:
        bank = build_bank(CHARACTERS, BrailleSpec())
        data = planted_pairs(bank, PLANT, ns.pairs, ns.seed, 64)
    perm = torch.randperm(ns.pairs, generator=torch.Generator().manual_seed(0))
    fit, held = perm[: ns.pairs // 2], perm[ns.pairs // 2 :]
    candidates = [c for c in DEFAULT_CANDIDATES if not (ns.withheld and c == "defocus_blur")]
    start = time.perf_counter()
    result = explain_gap(data, fit, held, candidates, seed=0, progress=False)
    selected = ", ".join(f"{r.effect} ({r.shrink:.3f})" for r in result.ranking) or "none"
    print(
        f"| {ns.contacts} | {'withheld' if ns.withheld else 'a candidate'} | {selected} | "
        f"{result.singles[0].effect} ({result.singles[0].shrink:.3f}) | "
        f"{result.gap_before:.3g} -> {result.gap_after:.3g} | {result.unexplained:.4f} | "
        f"{'yes' if result.residual_flagged else 'no'} | {time.perf_counter() - start:.0f} |"
    )


if __name__ == "__main__":
    main()
