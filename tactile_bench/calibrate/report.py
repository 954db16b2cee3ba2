"""``calibration.json`` and ``calibration.md``: what was fitted, how it scores, how to use it."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tactile_bench.calibrate.fit import ProfileFit
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.report import jsonable
from tactile_bench.io import atomic_write_json, atomic_write_text

NO_HELDOUT = (
    "--holdout 0: every pair was fitted, so nothing measures the profile; rerun with "
    "--holdout 0.5 (the default) to score it on pairs it was not fitted on"
)
ROWS = (("sim", "plain sim (our simulator on the real no-contact frame)"), ("profile", "profile"))


def summary(
    data: DiagnosisPairs,
    fitted: ProfileFit,
    holdout: float,
    seed: int,
    name: str,
    out: Path,
    source: str | None,
    digest: str,
) -> dict[str, Any]:
    """Everything ``calibration.json`` holds but the scores and the times."""
    n_fit = fitted.n_pairs
    return {
        "input": {"root": source, "hash": digest},
        "n_pairs": len(data),
        "n_fit": n_fit,
        "n_heldout": len(data) - n_fit,
        "holdout": holdout,
        "seed": seed,
        "size": data.size,
        "gel_mm": [float(v) for v in data.gel_mm],
        "profile": {"path": str(out / "profile.yaml"), "name": name, "effects": fitted.effects},
        "selected": fitted.selected,
        "selection": fitted.selection,
        "dropped": fitted.dropped,
        "geometry": fitted.geometry,
        "background_k": fitted.background["k"],
        "background": fitted.background,
        "noise": fitted.noise,
        "led_azimuth_deg": fitted.sensor["led_azimuth_deg"],
        "heldout": None,
        "heldout_note": NO_HELDOUT if holdout == 0 else "",
        "curve": None,
    }


def _num(value: Any, digits: int) -> str:
    """A score (a number, or a {mean, std} summary) to ``digits`` decimals."""
    if isinstance(value, Mapping):
        return f"{value['mean']:.{digits}f} +- {value.get('std', 0.0):.{digits}f}"
    return f"{float(value):.{digits}f}"


def _params(params: Mapping[str, float]) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in params.items()) or "its fit"


def _fitted_lines(r: Mapping[str, Any]) -> list[str]:
    sel, bg, noise = r["selection"], r["background"], r["noise"]
    chosen = [f"`{n}` ({_params(p)})" for n, p in r["selected"].items()] or ["nothing"]
    lines = [
        "## What was fitted (on the fit pairs only)",
        "",
        f"- **No-contact field**: {bg['k']} x {bg['k']} cosine terms of `background.png` "
        f"({bg['chosen_by']}).",
        f"- **Effects** the gap diagnosis selected on its own {sel['n_fit']} / "
        f"{sel['n_heldout']} split of the fit pairs: {'; '.join(chosen)}.",
    ]
    lines += [f"- Not carried into the profile: `{k}`: {why}." for k, why in r["dropped"].items()]
    geo = r["geometry"]
    lines.append(
        f"- **Gel geometry** refitted for the contact region ({geo['folds']}-fold CV on the "
        f"fit pairs): contact MSE {geo['cv_contact_mse_before']:.1f} -> "
        f"{geo['cv_contact_mse_after']:.1f}; the profile's effects are listed in profile.yaml."
    )
    read = noise.get("read_noise", 0.0)
    noise_text = f"read noise {read:g} grey levels" if read else "none"
    azimuths = ", ".join(f"{a:g}" for a in r["led_azimuth_deg"])
    return lines + [
        "- **Optical response**: the lookup (22 x 3 x 6) fitted on every fit pair under the "
        f"selected gel geometry, at blend 1; LED azimuths {azimuths} deg (R, G, B).",
        f"- **Camera noise**: {noise_text} ({noise['source']}).",
        "",
    ]


def _heldout_lines(r: Mapping[str, Any]) -> list[str]:
    lines = ["## Held-out pairs", ""]
    score = r["heldout"]
    if score is None:
        return [*lines, r["heldout_note"] + ".", ""]
    lines += [
        f"{r['n_heldout']} pairs the calibration never saw, {r['size']} x {r['size']} px; "
        "contact MSE is within two contact radii.",
        "",
        "| model | MSE | SSIM | contact MSE |",
        "| --- | --- | --- | --- |",
    ]
    for key, label in ROWS:
        s = score[key]
        lines.append(
            f"| {label} | {_num(s['mse'], 2)} | {_num(s['ssim'], 4)} | "
            f"{_num(s['contact_mse'], 2)} |"
        )
    return [*lines, ""]


def _curve_lines(r: Mapping[str, Any]) -> list[str]:
    curve = r["curve"]
    if not curve:
        return []
    lines = [
        "## Presses needed (`--curve`)",
        "",
        "Nested seeded subsets of the fit pairs, each calibrated alone and scored on the same "
        f"held-out pairs (plain sim: contact MSE {curve['sim']['contact_mse']:.2f}).",
        "",
        "| presses | contact MSE | MSE | SSIM | selected |",
        "| --- | --- | --- | --- | --- |",
    ]
    for row in curve["rows"]:
        lines.append(
            f"| {row['n_presses']} | {row['contact_mse']:.2f} | {row['mse']:.2f} | "
            f"{row['ssim']:.4f} | {', '.join(row['selected']) or 'nothing'} |"
        )
    return [*lines, "", "![held-out contact MSE against presses](curve.png)", ""]


def markdown(r: Mapping[str, Any]) -> str:
    """The text of ``calibration.md``."""
    path = r["profile"]["path"]
    head = [
        f"# Calibration `{r['profile']['name']}`",
        "",
        f"{r['n_pairs']} pairs of `{r['input']['root']}` at {r['size']} x {r['size']} px "
        f"(gel view {r['gel_mm'][0]:g} x {r['gel_mm'][1]:g} mm): {r['n_fit']} fitted, "
        f"{r['n_heldout']} held out (`--holdout {r['holdout']:g}`, seed {r['seed']}).",
        "",
    ]
    usage = [
        "## Using the profile",
        "",
        f"Wherever a command takes a profile: `--profile {path}`, e.g.",
        "",
        f"    python -m tactile_bench export-pairs --generate 300 --profile {path} --out pairs/",
        "",
        f"In a recipe, as a second sensor unit: `second_unit: {path}`.",
        "",
        "Seconds per step: " + ", ".join(f"{k} {v:g}" for k, v in r["timing_s"].items()) + ".",
        "",
    ]
    body = _fitted_lines(r) + _heldout_lines(r) + _curve_lines(r)
    return "\n".join(head + body + usage)


def write_report(folder: Path, result: Mapping[str, Any]) -> None:
    """``calibration.json`` and ``calibration.md`` in ``folder``."""
    atomic_write_json(folder / "calibration.json", jsonable(result))
    atomic_write_text(folder / "calibration.md", markdown(result))
