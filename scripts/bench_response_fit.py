"""How long one fit of the optical-response lookup takes, the way the diagnosis refits it.

    python scripts/bench_response_fit.py PAIRED_DIR [--pairs 150] [--repeats 3]

PAIRED_DIR is the paired layout (``export-pairs --generate 300 --out DIR``). The diagnosis
refits the lookup under every gel geometry it tries, on the fit split (half the pairs), so a
fit's cost is paid dozens of times per diagnosis. Prints one JSON line: the CPU capability,
the seconds of ``sensor.response_fit.fit_response`` (float32 products over every pixel,
summed in float64) and of the float64 reference that gathers the contact pixels first (the
form it replaced), their ratio, and the largest difference of the two tables relative to
the table's largest entry.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np
import torch

from tactile_bench.diagnose.paired import load_paired
from tactile_bench.sensor.response_fit import RIDGE, fit_response, response_design


def float64_gathered(
    surface: torch.Tensor, delta: torch.Tensor, gel_mm: tuple[float, float]
) -> np.ndarray:
    """The reference: normal equations in float64 over the pixels with any feature."""
    n_cols = response_design(surface[:1, :, :2, :2], gel_mm).shape[-1]
    xtx = torch.zeros(n_cols, n_cols, dtype=torch.float64)
    xty = torch.zeros(n_cols, 3, dtype=torch.float64)
    for k in range(0, surface.shape[0], 8):
        x = response_design(surface[k : k + 8], gel_mm).reshape(-1, n_cols)
        y = delta[k : k + 8].permute(0, 2, 3, 1).reshape(-1, 3)
        active = x.abs().amax(1) > 0
        x, y = x[active].double(), y[active].double()
        xtx += x.T @ x
        xty += x.T @ y
    lam = RIDGE * float(torch.diagonal(xtx).mean())
    w = torch.linalg.solve(xtx + lam * torch.eye(n_cols, dtype=torch.float64), xty)
    return w.reshape(n_cols // 6, 6, 3).permute(0, 2, 1).numpy()


def seconds(fn: Callable[[], np.ndarray], repeats: int) -> tuple[float, np.ndarray]:
    start = time.perf_counter()
    for _ in range(repeats):
        table = fn()
    return (time.perf_counter() - start) / repeats, table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paired_dir")
    parser.add_argument("--pairs", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    data = load_paired(args.paired_dir)
    depth = data.depth[: args.pairs]
    delta = (data.real[: args.pairs] - data.background[None]).float()
    gel = tuple(data.gel_mm)
    now, table = seconds(lambda: fit_response(depth, delta, gel), args.repeats)
    ref, reference = seconds(lambda: float64_gathered(depth, delta, gel), args.repeats)
    print(
        json.dumps(
            {
                "cpu_capability": torch.backends.cpu.get_cpu_capability(),
                "threads": torch.get_num_threads(),
                "pairs": len(depth),
                "size": data.size,
                "fit_response_s": round(now, 3),
                "float64_gathered_s": round(ref, 3),
                "speedup": round(ref / now, 2),
                "max_relative_difference": float(
                    np.abs(table - reference).max() / np.abs(reference).max()
                ),
            }
        )
    )


if __name__ == "__main__":
    main()
