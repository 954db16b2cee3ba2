"""Real GelSight presses as a test bench: ground a profile, refit it, export real pairs.

The orchestration over the layers (data: ``data.ball_presses``; sensor: the surrogate and
``sensor.press_grounding``; metrics) for the real frames of Taxim's calibration packs. Every
measurement here is on the held-out (odd-numbered) presses; the profiles' numbers come from
the even ones.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
import torch.nn.functional as F

from tactile_bench.data.ball_presses import TAXIM_SENSORS, BallPresses, load_ball_presses
from tactile_bench.data.corpus import CorpusPairs, load_pairs
from tactile_bench.data.ycb_slide import build_ycb_slide_standin
from tactile_bench.diagnose.paired import (
    DIGIT_GEL_MM,
    GEL_FILE,
    DiagnosisPairs,
    detect_layout,
    load_paired,
    read_gel,
)
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.args import MAX_SIZE
from tactile_bench.metrics.encoder import fit_encoder, kid
from tactile_bench.metrics.image import ssim_mse
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.pair_scoring import render_pairs, score_profile
from tactile_bench.sensor.press_grounding import (
    fit_sensor,
    format_fit_module,
    press_figure,
    press_metrics,
    sim_render,
    summarise,
)
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.translators.base import Translator, image_to_foreground
from tactile_bench.translators.registry import create_translator

FIT_HW = (96, 128)  # a fifth of the 480 x 640 frame, 4:3 kept: the size the fits run at
SOURCE = "taxim 1.4.1 (PyPI, MIT), taxim/calib/{gelsight,gelsight_mini}/ dataPack.npz, params.json"


def _pool(x: torch.Tensor, size: int) -> torch.Tensor:
    return F.adaptive_avg_pool2d(x, (size, size))


def profile_sensor(profile: str) -> tuple[SurrogateDigit, str]:
    """The profile and the Taxim sensor whose real presses can ground it."""
    surrogate = SurrogateDigit.from_profile(profile)
    if surrogate.sensor not in TAXIM_SENSORS:
        raise TactileBenchError(
            f"--profile {profile}: models the {surrogate.sensor!r} sensor, which has no real "
            f"presses here; profiles with presses: {', '.join(TAXIM_SENSORS)} (for the DIGIT, "
            "run ground without --profile)"
        )
    return surrogate, surrogate.sensor


def heldout_presses(sensor: str, size: int = 64) -> BallPresses:
    """The odd-numbered presses, depth at 2 x ``size`` (the render's oversampling)."""
    presses = load_ball_presses(sensor, 2 * size)
    return presses.subset(presses.halves()[1])


def ground_profile(profile: str, size: int = 64, seed: int = 0, figure: Path | None = None) -> dict:
    """Surrogate profile and simple simulator against the held-out real presses.

    Rows per frame: MSE and SSIM over the frame and MSE within two contact radii, for the
    surrogate (as it renders, noise included, seeded), the simple simulator composited on the
    real no-contact frame (TACTO's recipe), and the no-contact frame alone (no contact
    modelled at all: the floor every model must beat).
    """
    start = time.perf_counter()
    surrogate, sensor = profile_sensor(profile)
    test = heldout_presses(sensor, size)
    renders = render_pairs(
        surrogate, test.depth, test.real, test.background, surrogate.gel(size), seed
    )
    real, depth = renders.real, renders.depth
    images = {
        "sim": renders.sim,
        "surrogate": renders.profile,
        "no contact": renders.background.expand_as(real),
    }
    mask = renders.mask
    rows = {name: press_metrics(img, real, mask) for name, img in images.items()}
    if figure is not None:
        columns = {
            "our sim": images["sim"],
            f"surrogate ({profile})": images["surrogate"],
            "real": real,
        }
        press_figure(depth, columns, figure)
    return {
        "profile": profile,
        "sensor": sensor,
        "source": str(test.source),
        "presses": test.names,
        "heldout_indices": test.index.tolist(),
        "size": size,
        "ball_radius_mm": test.ball_radius_mm,
        "per_frame": rows,
        "summary": {name: summarise(r) for name, r in rows.items()},
        "seconds": round(time.perf_counter() - start, 2),
    }


#: how far a paired folder's gel view may differ from a profile's (each side, relative)
GEL_TOLERANCE = 0.02


def check_gel_match(
    pairs_dir: Path, folder_gel: tuple[float, float], profile: str, profile_gel: GelSpec
) -> None:
    """A profile renders its own gel view: pairs of another view (more than 2% apart on a
    side) would be scored against frames of another geometry. Refused in one line."""
    ours = (profile_gel.width_mm, profile_gel.height_mm)
    if all(abs(a / b - 1) <= GEL_TOLERANCE for a, b in zip(folder_gel, ours, strict=True)):
        return
    gel_file = pairs_dir / GEL_FILE
    where = f"{gel_file}:" if gel_file.exists() else f"{pairs_dir}: no {GEL_FILE}, so"
    raise TactileBenchError(
        f"{where} the pairs show a {folder_gel[0]:g} x {folder_gel[1]:g} mm gel view but "
        f"--profile {profile} renders {ours[0]:g} x {ours[1]:g} mm (more than "
        f"{GEL_TOLERANCE:.0%} apart): give a profile of that sensor, or fix {GEL_FILE}"
    )


def ground_pairs(profile: str, pairs_dir: Path, size: int = 64, seed: int = 0) -> dict:
    """A profile (name or YAML path) and the plain simulator against every pair of a paired
    folder (``diagnose.paired``'s layout: depth/, real/, background.png, gel.json; sim/ is
    not used). Read at twice ``size`` (the profile's oversampling), scored at ``size``."""
    start = time.perf_counter()
    if 2 * size > MAX_SIZE:
        raise TactileBenchError(
            f"--size: at most {MAX_SIZE // 2} with --pairs (depth is read at twice the size)"
        )
    surrogate = SurrogateDigit.from_profile(profile)
    pairs_dir = Path(pairs_dir)
    layout, base = detect_layout(pairs_dir)
    if layout != "paired" or (base / "depth").is_dir():  # else load_paired names depth/
        folder_gel = read_gel(base) if layout == "paired" else DIGIT_GEL_MM
        check_gel_match(pairs_dir, folder_gel, profile, surrogate.gel(size))  # before reading
    data = load_paired(base, 2 * size, render_missing_sim=True)
    report = score_profile(
        surrogate, data.depth, data.real, data.background, data.gel_mm, size, seed
    )
    return report | {
        "profile_name": profile,
        "pairs": str(pairs_dir),
        "gel_mm": list(data.gel_mm),
        "size": size,
        "seconds": round(time.perf_counter() - start, 2),
    }


def print_ground_pairs(report: dict) -> None:
    """``ground --pairs``: the two models' means +- std over the pairs as a short table."""
    w, h = report["gel_mm"]
    print(
        f"profile {report['profile_name']} against {report['n_pairs']} pairs of {report['pairs']} "
        f"({w:g} x {h:g} mm gel view), {report['size']} x {report['size']}"
    )
    print(f"  {'model':<12} {'MSE':>14} {'SSIM':>16} {'contact MSE':>16}")
    for name in ("sim", "profile"):
        m = summarise(report["per_frame"][name])
        print(
            f"  {name:<12} {m['mse']['mean']:>7.1f} +- {m['mse']['std']:<5.1f}"
            f" {m['ssim']['mean']:>7.4f} +- {m['ssim']['std']:<6.4f}"
            f" {m['contact_mse']['mean']:>7.1f} +- {m['contact_mse']['std']:<5.1f}"
        )
    print(f"  {report['seconds']:.1f} s")


def press_pairs(sensor: str, size: int = 64) -> DiagnosisPairs:
    """Every press of ``sensor`` as a diagnosis pair: depth, our simulator's image, the real frame.

    The simulator's image is TACTO's recipe: the simple simulator's noise-free colour change
    composited onto the sensor's real no-contact frame, which is therefore both backgrounds.
    """
    presses = load_ball_presses(sensor, size)
    gel = GelSpec(*presses.gel_mm, size=size)
    sim = sim_render(presses.depth, presses.background, gel)
    return DiagnosisPairs(
        depth=presses.depth,
        sim=sim,
        real=presses.real,
        background=presses.background,
        sim_background=presses.background,
        labels=[""] * len(presses),
        names=presses.names,
        gel_mm=presses.gel_mm,
    )


def refit_module(sensors: tuple[str, ...] = tuple(TAXIM_SENSORS)) -> str:
    """Refit every Taxim sensor from its even presses: the text of ``effects/_taxim_fit.py``."""
    fits = {}
    for sensor in sensors:
        presses = load_ball_presses(sensor, FIT_HW)
        fit = presses.subset(presses.halves()[0])
        fits[sensor] = fit_sensor(fit.depth, fit.real, fit.background, presses.gel_mm)
    return format_fit_module(fits, SOURCE)


def print_ground(report: dict) -> None:
    """The held-out comparison as a short table and a per-frame listing."""
    s = report["summary"]
    print(
        f"profile {report['profile']} against {len(report['presses'])} held-out real "
        f"{report['sensor']} presses ({report['source']}), {report['size']} x "
        f"{report['size']}, ball radius {report['ball_radius_mm']} mm"
    )
    print(f"  {'model':<12} {'MSE':>14} {'SSIM':>16} {'contact MSE':>16}")
    for name, m in s.items():
        print(
            f"  {name:<12} {m['mse']['mean']:>7.1f} +- {m['mse']['std']:<5.1f}"
            f" {m['ssim']['mean']:>7.4f} +- {m['ssim']['std']:<6.4f}"
            f" {m['contact_mse']['mean']:>7.1f} +- {m['contact_mse']['std']:<5.1f}"
        )
    print(
        "  per frame (MSE / SSIM): "
        + "; ".join(
            f"{name} "
            + " ".join(f"{r['mse']:.0f}/{r['ssim']:.3f}" for r in report["per_frame"][name])
            for name in ("surrogate", "sim")
        )
    )
    print(f"  {report['seconds']:.1f} s")


def _image_rows(
    images: dict[str, torch.Tensor], real: torch.Tensor, encoder_images: torch.Tensor
) -> dict[str, dict]:
    """SSIM, MSE (paired) and KID (encoder fitted on the fitting half's real frames)."""
    encoder = fit_encoder(encoder_images, steps=200, batch_size=min(64, len(encoder_images)))
    with torch.no_grad():
        real_features = encoder.features(real)
        rows = {}
        for name, img in images.items():
            row = ssim_mse(img, real)
            # subsets of half the set: with all of it every subset would be the same draw
            mean, std = kid(encoder.features(img), real_features, 50, max(2, len(real) // 2))
            rows[name] = {**row, "kid": mean, "kid_std": std}
    return rows


def translators_on_presses(
    sensor: str,
    out_dir: Path,
    size: int = 64,
    pretrain_pairs: int = 600,
    pretrain_steps: int = 100,
    finetune_steps: int = 60,
    cgan_steps: int = 200,
    seed: int = 0,
) -> dict:
    """The paper's image-similarity claim on real frames: translators fitted on half the presses.

    Diffusion: pretrained on the stand-in YCB-Slide corpus rendered by the calibrated sim
    (this sensor's profile, whose numbers come from the fitting half), then fine-tuned on the
    fitting half's real presses. cGAN: trained on the fitting half. Every row is measured on
    the held-out half against its real frames, each composited on the real no-contact
    frame: plain sim, the calibrated sim, the cGAN, the diffusion translator.
    """
    start = time.perf_counter()
    profile = SurrogateDigit.from_profile(sensor)
    presses = load_ball_presses(sensor, 2 * size)
    fit_idx, test_idx = presses.halves()
    depth = _pool(presses.depth, size)
    real = _pool(presses.real, size)
    background = _pool(presses.background[None], size)[0]
    gel = profile.gel(size)
    seconds: dict[str, float] = {}

    t = time.perf_counter()
    build_ycb_slide_standin(
        out_dir / "corpus", pretrain_pairs, gel=gel, real_sensor=profile, seed=seed
    )
    corpus = load_pairs(out_dir / "corpus", "train")
    seconds["corpus"] = time.perf_counter() - t
    fit_depth, fit_fg = depth[fit_idx], image_to_foreground(real[fit_idx], background)

    finetuned, cgan, fit_seconds = _fit_translators(
        corpus, fit_depth, fit_fg, out_dir, (pretrain_steps, finetune_steps, cgan_steps), seed
    )
    seconds |= fit_seconds

    test_depth, test_real = depth[test_idx], real[test_idx]
    generator = torch.Generator().manual_seed(seed)
    images = {
        "sim": sim_render(test_depth, background, gel),
        # on the real no-contact frame like every other row (TACTO's recipe), so the rows
        # differ in the contact only, not in how well a background is modelled
        "calibrated sim": profile.render_surface(
            presses.depth[test_idx], gel, torch.Generator().manual_seed(seed)
        )
        - profile.background(gel)
        + background,
        "cgan": cgan.translate(test_depth, background, generator),
        "diffusion": finetuned.translate(test_depth, background, generator),
    }
    rows = _image_rows(images, test_real, real[fit_idx])
    press_figure(test_depth, {**images, "real": test_real}, out_dir / "samples.png")
    return {
        "sensor": sensor,
        "n_fit": len(fit_idx),
        "n_heldout": len(test_idx),
        "pretrain_pairs": pretrain_pairs,
        "steps": {"pretrain": pretrain_steps, "finetune": finetune_steps, "cgan": cgan_steps},
        "rows": {k: {m: round(v, 4) for m, v in r.items()} for k, r in rows.items()},
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
        "total_seconds": round(time.perf_counter() - start, 1),
        "figure": str(out_dir / "samples.png"),
    }


def _fit_translators(
    corpus: CorpusPairs,
    fit_depth: torch.Tensor,
    fit_fg: torch.Tensor,
    out_dir: Path,
    steps: tuple[int, int, int],
    seed: int,
) -> tuple[Translator, Translator, dict[str, float]]:
    """Diffusion pretrained on the corpus then fine-tuned on the fitting half, and the cGAN
    on that half, with (pretrain, finetune, cgan) ``steps``; and each fit's seconds."""
    pretrain_steps, finetune_steps, cgan_steps = steps
    seconds: dict[str, float] = {}
    t = time.perf_counter()
    diffusion = create_translator(
        "diffusion", {"max_steps": pretrain_steps, "batch_size": 16, "lr": 5e-4, "seed": seed}
    )
    diffusion.fit_pairs(corpus.depth, corpus.foreground("real"), out_dir / "pretrain")
    seconds["diffusion_pretrain"] = time.perf_counter() - t
    t = time.perf_counter()
    finetuned = create_translator(
        "diffusion", {"max_steps": finetune_steps, "batch_size": 8, "lr": 2e-4, "seed": seed}
    )
    finetuned.load_state_dict(diffusion.state_dict())
    finetuned.fit_pairs(fit_depth, fit_fg, out_dir / "finetune")
    seconds["diffusion_finetune"] = time.perf_counter() - t
    t = time.perf_counter()
    cgan = create_translator("cgan", {"max_steps": cgan_steps, "batch_size": 8, "seed": seed})
    cgan.fit_pairs(fit_depth, fit_fg, out_dir / "cgan")
    seconds["cgan"] = time.perf_counter() - t
    return finetuned, cgan, seconds
