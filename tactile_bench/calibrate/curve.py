"""How many presses a calibration needs: the same calibration on nested subsets of the fit
pairs (4, 8, 16, ... and all of them), each scored on the same held-out pairs."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.diagnose.paired import DiagnosisPairs

log = logging.getLogger("tactile_bench")

FIRST_POINT = 4  # the fewest pairs a calibration runs on (``run.MIN_FIT``)
METRICS = ("contact_mse", "mse", "ssim")


def curve_sizes(n_fit: int, first: int = FIRST_POINT) -> list[int]:
    """4, 8, 16, ... below ``n_fit``, then ``n_fit`` itself."""
    sizes, k = [], first
    while k < n_fit:
        sizes.append(k)
        k *= 2
    return [*sizes, n_fit]


def mean_of(value: Any) -> float:
    """A score as a number: a plain number, or the mean of a {mean, std} summary."""
    if isinstance(value, Mapping):
        return float(value["mean"])
    return float(value)


def _row(n: int, score: Mapping[str, Any], selected: Sequence[str], secs: float) -> dict:
    row: dict[str, Any] = {"n_presses": n}
    row.update({k: mean_of(score["profile"][k]) for k in METRICS if k in score["profile"]})
    return {**row, "selected": list(selected), "seconds": round(secs, 2)}


def calibration_curve(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    full_score: Mapping[str, Any],
    full_selected: Sequence[str],
    seed: int,
    candidates: Sequence[str] | None,
    figure: Path,
) -> dict[str, Any]:
    """Calibrate on nested seeded subsets of ``fit_idx`` and score each on ``held_idx``;
    the last point (every fit pair) is the main calibration (``full_score``,
    ``full_selected``). Draws
    ``figure`` and returns the rows with the plain sim's held-out figures."""
    from tactile_bench.calibrate.fit import fit_sensor_profile
    from tactile_bench.calibrate.profiles import in_memory_profile, score_heldout

    order = fit_idx[torch.from_numpy(np.random.default_rng(seed).permutation(len(fit_idx)))]
    held = data.subset(held_idx)
    sizes = curve_sizes(len(fit_idx))
    rows = []
    for n in sizes[:-1]:
        t = time.perf_counter()
        subset = data.subset(order[:n].sort().values)
        fitted = fit_sensor_profile(subset, seed, candidates, progress=False, what=f"{n} pairs")
        score = score_heldout(in_memory_profile(fitted, "curve"), held, seed)
        rows.append(_row(n, score, list(fitted.selected), time.perf_counter() - t))
        log.info("curve: %d presses, held-out contact MSE %.2f", n, rows[-1]["contact_mse"])
    rows.append(_row(sizes[-1], full_score, full_selected, 0.0) | {"seconds": None})
    sim = {k: mean_of(full_score["sim"][k]) for k in METRICS if k in full_score["sim"]}
    plot_curve(rows, sim["contact_mse"], figure)
    return {"rows": rows, "sim": sim, "nested": True, "seed": seed}


def plot_curve(rows: Sequence[Mapping[str, Any]], sim_contact_mse: float, path: Path) -> Path:
    """Held-out contact MSE against the number of presses (log2 axis), plain sim dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    n = [r["n_presses"] for r in rows]
    fig, ax = plt.subplots(figsize=(5.0, 3.4))
    ax.plot(n, [r["contact_mse"] for r in rows], "o-", label="calibrated profile")
    ax.axhline(sim_contact_mse, color="grey", linestyle="--", label="plain sim")
    ax.set_xscale("log", base=2)
    ax.set_xticks(n, [str(v) for v in n])
    ax.set_xlabel("presses calibrated on")
    ax.set_ylabel("held-out contact MSE")
    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
