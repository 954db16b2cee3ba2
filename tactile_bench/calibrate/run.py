"""``calibrate``: split the pairs, fit a profile on the fit half, score it on the held-out half.

``calibrate_pairs`` is the whole command on loaded pairs (the CLI and a pipeline stage call
it): it writes ``profile.yaml``, ``calibration.json``, ``calibration.md`` (and ``curve.png``
with ``curve``) into a temporary folder next to ``out_dir`` and renames it into place at the
end, so a failure leaves nothing half-written. Only the user's pairs are read.
"""

from __future__ import annotations

import logging
import math
import os
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from tactile_bench.calibrate.fit import fit_sensor_profile
from tactile_bench.calibrate.profiles import score_heldout, write_fitted_profile
from tactile_bench.diagnose.paired import DiagnosisPairs, data_hash
from tactile_bench.diagnose.run import stratified_split
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_folder
from tactile_bench.sensor.surrogate import SurrogateDigit

log = logging.getLogger("tactile_bench")

DEFAULT_HOLDOUT = 0.5  # 1 - the diagnosis's default --fit-fraction (its held-out share)
MIN_FIT = 4  # the effect selection's own split: 2 pairs to fit, 2 to check
MIN_HELD = 2  # held-out pairs to score the profile on
PROFILE_FILE = "profile.yaml"
JSON_FILE = "calibration.json"
MD_FILE = "calibration.md"
CURVE_FILE = "curve.png"
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


# ----------------------------------------------------------------------------- checks
def check_holdout(holdout: float, curve: bool = False) -> None:
    """``holdout`` in [0, 1); ``curve`` needs held-out pairs. One line each otherwise."""
    if not (math.isfinite(holdout) and 0 <= holdout < 1):
        raise TactileBenchError(
            f"--holdout: the held-out share must be in [0, 1), got {holdout:g} "
            f"(default {DEFAULT_HOLDOUT:g}; 0 fits on every pair)"
        )
    if curve and holdout == 0:
        raise TactileBenchError(
            "--curve: needs held-out pairs to score each point on; give --holdout above 0"
        )


def check_out_dir(out_dir: str | os.PathLike, overwrite: bool) -> Path:
    """``out_dir`` may be written: absent, empty, or replaced with ``overwrite``."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise TactileBenchError(f"{out}: exists and is not a folder; give --out a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise TactileBenchError(f"{out}: exists and is not empty; pass --overwrite to replace it")
    return out


def min_pairs(holdout: float) -> int:
    """The fewest pairs that leave ``MIN_FIT`` to fit and ``MIN_HELD`` held out."""
    if holdout == 0:
        return MIN_FIT
    return max(math.ceil(MIN_FIT / (1 - holdout) - 1e-9), math.ceil(MIN_HELD / holdout - 1e-9))


def split_pairs(
    data: DiagnosisPairs, holdout: float, seed: int, what: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """(fit, held-out) indices: each label split ``1 - holdout`` to the fit half, seeded
    (``diagnose.run.stratified_split``); ``holdout`` 0: every pair fits, none is held out."""
    n, need = len(data), min_pairs(holdout)
    fit, held = torch.arange(n), torch.zeros(0, dtype=torch.long)
    if n >= need and holdout > 0:
        fit, held = stratified_split(data.labels, 1 - holdout, seed)
    if n < need or len(fit) < MIN_FIT or (holdout > 0 and len(held) < MIN_HELD):
        split = f" (split {len(fit)} / {len(held)} by label)" if n >= need else ""
        raise TactileBenchError(
            f"{what}: {n} pairs{split}; calibrate needs at least {MIN_FIT} to fit (the effect "
            f"selection fits on half of them and checks on the rest) and {MIN_HELD} held out: "
            f"{need} or more with --holdout {holdout:g}; add pairs (or lower --holdout)"
        )
    return fit, held


def profile_name(what: str) -> str:
    """A sensor name for the profile, from the pairs' folder name."""
    name = _UNSAFE.sub("-", Path(what).name).strip("-._")[:64]
    return name or "calibrated"


# ----------------------------------------------------------------------------- output
def calibrate_pairs(
    data: DiagnosisPairs,
    out_dir: str | os.PathLike,
    holdout: float = DEFAULT_HOLDOUT,
    seed: int = 0,
    curve: bool = False,
    progress: bool = True,
    overwrite: bool = False,
    candidates: Sequence[str] | None = None,
    source: str | None = None,
) -> dict[str, Any]:
    """Calibrate a profile to ``data`` and write it with its report into ``out_dir``
    (module docstring); returns what ``calibration.json`` holds. ``source`` names the
    pairs (their folder) in messages and the profile; ``candidates`` limits the effects
    the selection searches (None: every diagnosis candidate)."""
    from tactile_bench.calibrate.curve import calibration_curve
    from tactile_bench.calibrate.report import summary, write_report

    start = time.perf_counter()
    check_holdout(holdout, curve)
    out = check_out_dir(out_dir, overwrite)
    what = source or "pairs"
    fit_idx, held_idx = split_pairs(data, holdout, seed, what)
    split_s = round(time.perf_counter() - start, 2)
    log.info("split: %d pairs, %d fit / %d held out", len(data), len(fit_idx), len(held_idx))
    fitted = fit_sensor_profile(data.subset(fit_idx), seed, candidates, progress, what)
    timing = {"split": split_s, **fitted.timing_s}
    name = profile_name(what)
    result = summary(data, fitted, holdout, seed, name, out, source, data_hash(data))
    with atomic_folder(out) as tmp:
        path = write_fitted_profile(tmp / PROFILE_FILE, fitted, name, what)
        if len(held_idx):
            t = time.perf_counter()
            held = data.subset(held_idx)
            result["heldout"] = score_heldout(SurrogateDigit.from_profile(path), held, seed)
            timing["scoring"] = round(time.perf_counter() - t, 2)
            log.info("scoring: %d held-out pairs (%.1f s)", len(held), timing["scoring"])
        if curve:
            t = time.perf_counter()
            result["curve"] = calibration_curve(
                data,
                fit_idx,
                held_idx,
                result["heldout"],
                list(fitted.selected),
                seed,
                candidates,
                tmp / CURVE_FILE,
            )
            timing["curve"] = round(time.perf_counter() - t, 2)
        timing["total"] = round(time.perf_counter() - start, 2)
        result["timing_s"] = timing
        write_report(tmp, result)
    return result
