"""Which physical effect carries the gap on real GelSight frames: one change at a time.

    python scripts/press_ablation.py [--sensors gelsight gelsight-mini] [--json OUT]

Every row is fitted on the even-numbered real presses of Taxim's packs and measured on the
odd ones (needs ``pip install -e '.[real]'``). Rows change one thing against the fitted
profile's core (fitted response on the elastically spread gel, ball radius 2 mm):
the shading law (the simple simulator's Phong lights instead of the fitted response), the
gel (rigid instead of spread), the ball radius, and shadows added on top of the profile.
Composited on the real no-contact frame and noise-free, so rows differ only in the contact.
"""

from __future__ import annotations

import argparse
import json
import time

import torch
import torch.nn.functional as F

from tactile_bench.data.ball_presses import load_ball_presses
from tactile_bench.effects._taxim_fit import SENSORS
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.press_grounding import contact_mask, sim_render, spread
from tactile_bench.sensor.response_fit import fit_response, predict_delta
from tactile_bench.sensor.surrogate import SurrogateDigit

FIT_HW = (96, 128)


def _metrics(pred: torch.Tensor, real: torch.Tensor, mask: torch.Tensor) -> dict[str, float]:
    err = (pred.clamp(0, 255) - real) ** 2
    return {
        "mse": round(float(err.mean()), 2),
        "contact_mse": round(float(err[mask.expand_as(err)].mean()), 2),
    }


def _fitted(depth_fit, real_fit, depth_test, bg, gel_mm, sigma):
    w = fit_response(spread(depth_fit, sigma, gel_mm), real_fit - bg, gel_mm)
    return bg + predict_delta(spread(depth_test, sigma, gel_mm), w, gel_mm)


def ablate(sensor: str) -> list[dict]:
    """The rows for one sensor (see the module docstring)."""
    sigma = SENSORS[sensor]["elastic_sigma_mm"]
    rows = []
    for radius in (2.0, 2.38, 3.0):
        p = load_ball_presses(sensor, FIT_HW, ball_radius_mm=radius)
        fit, test = p.halves()
        bg, gel_mm = p.background, p.gel_mm
        real, mask = p.real[test], contact_mask(p.depth[test])
        variants = {f"fitted response, spread {sigma} mm, ball R {radius} mm": sigma}
        if radius == 2.0:
            variants["fitted response, rigid gel"] = 0.0
        for name, s in variants.items():
            pred = _fitted(p.depth[fit], p.real[fit], p.depth[test], bg, gel_mm, s)
            rows.append({"row": name, **_metrics(pred, real, mask)})
        if radius != 2.0:
            continue
        gel = GelSpec(*gel_mm, size=FIT_HW[1])
        for name, s in (
            ("simulator shading, rigid gel", 0.0),
            (f"simulator shading, spread {sigma} mm", sigma),
        ):
            surface = spread(p.depth[test], s, gel_mm)
            pred = sim_render(surface, bg, gel)
            rows.append({"row": name, **_metrics(pred, real, mask)})
        rows.append({"row": "no contact modelled", **_metrics(bg.expand_as(real), real, mask)})
        # shadows on top of the whole profile (noise off), at the project's 64 x 64
        profile = SurrogateDigit.from_profile(sensor).without("camera_noise")
        big = load_ball_presses(sensor, 128, ball_radius_mm=radius)
        real64 = F.adaptive_avg_pool2d(big.real[test], (64, 64))
        bg64 = F.adaptive_avg_pool2d(big.background[None], (64, 64))[0]
        mask64 = contact_mask(F.adaptive_avg_pool2d(big.depth[test], (64, 64)))
        for strength in (0.0, 0.25, 0.5):
            s = profile if strength == 0 else profile.with_params("shadows", strength=strength)
            g = s.gel(64)
            pred = s.render_surface(big.depth[test], g) - s.background(g) + bg64
            rows.append(
                {
                    "row": f"64 x 64 profile, shadows strength {strength}",
                    **_metrics(pred, real64, mask64),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", nargs="+", default=list(SENSORS))
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()
    out = {}
    for sensor in args.sensors:
        start = time.perf_counter()
        out[sensor] = ablate(sensor)
        print(f"{sensor} (held-out odd presses; {time.perf_counter() - start:.1f} s)")
        print(f"  {'row':<52} {'MSE':>8} {'contact MSE':>12}")
        for r in out[sensor]:
            print(f"  {r['row']:<52} {r['mse']:>8.2f} {r['contact_mse']:>12.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
