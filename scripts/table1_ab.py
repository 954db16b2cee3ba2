"""A/B experiments behind docs/results/table1.md, on a finished ``table1.yaml`` run directory.

Each experiment changes one thing against the table's own protocol and prints one JSON row
a condition (mean and per-seed accuracy on the real classifier test set):

    python scripts/table1_ab.py finetune RUN_DIR   # fraction vs optimiser steps vs yaw vs lr
    python scripts/table1_ab.py cgan RUN_DIR       # what in the cGAN images fails on real
    python scripts/table1_ab.py cgan_lowpass RUN_DIR  # ... with fine detail removed both sides
    python scripts/table1_ab.py cgan_noise RUN_DIR    # ... with the diffusion's camera noise added
    python scripts/table1_ab.py cgan_bands RUN_DIR    # ... coarse / fine detail swapped with real's
    python scripts/table1_ab.py cgan_three_bands RUN_DIR  # ... its middle or coarse band alone
    python scripts/table1_ab.py cgan_coarse_gain RUN_DIR  # ... its coarse band: strength or shape
    python scripts/table1_ab.py cgan_coarse_where RUN_DIR # where that band departs from real's
    python scripts/table1_ab.py cgan_coarse_place RUN_DIR # ... that band near / away from contacts
    python scripts/table1_ab.py cgan_mean_colour RUN_DIR  # ... its per-image mean colour offset
    python scripts/table1_ab.py cgan_away_pattern RUN_DIR # ... does that part name the letter
    python scripts/table1_ab.py cgan_halo RUN_DIR  # ... is that part a blurred copy of the contact
    python scripts/table1_ab.py rotated RUN_DIR    # every row's models on the yaw-to-90 test set
    python scripts/table1_ab.py legibility RUN_DIR # every row's models on each translator's
                                                   # rendering of the classifier test contacts
    python scripts/table1_ab.py ssim RUN_DIR       # SSIM / MSE on and off the contacts; the
                                                   # diffusion with and without its camera noise
    python scripts/table1_ab.py footprint RUN_DIR  # each rendering's contact: contrast, spread
                                                   # past the contact, share of fine detail

``finetune`` starts from the run's ``classify_sim`` models and fine-tunes them as the classify
stage does, with the classifier settings of table1.yaml's fine-tuning rows (``--lr`` sets
the base lr the conditions vary around). ``cgan`` trains the base classifier on the run's
cGAN images. Both write nothing into the run directory (their scratch goes to ``--out``).
``--cgan-stage`` points the cgan_* experiments at another translate stage of the run, e.g. a
generator variant of ``scripts/cgan_generator_ab.yaml``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d
from torchmetrics.functional.image import structural_similarity_index_measure

from tactile_bench.classify.store import load_classifier
from tactile_bench.classify.train import (
    ClassifierConfig,
    evaluate,
    recalibrate_batchnorm,
    train_classifier,
)
from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.datamodule import stratified_split, stratified_subset
from tactile_bench.data.pixels import to_uint8
from tactile_bench.metrics.noise import estimate_pixel_noise
from tactile_bench.translators import image_to_foreground
from tactile_bench.translators.registry import translator_class

SEEDS = (0, 1, 2)
N_CLASSES = 27
#: the translate stage whose images the cgan_* experiments take (``--cgan-stage``)
cgan_stage = "translate_cgan"
QUIET = {"enable_progress_bar": False, "enable_checkpointing": False}


def _stage(run: Path, name: str) -> Path:
    found = sorted(run.glob(f"{name}-*"))
    if not found:
        raise SystemExit(f"error: {run}: no stage directory {name}-*")
    return found[0]


def _report(name: str, accs: list[float], **extra: object) -> None:
    a = np.asarray(accs)
    row = {"cond": name, "mean": round(float(a.mean()), 2), "std": round(float(a.std(ddof=1)), 2)}
    print(json.dumps(row | {"per_seed": [round(x, 2) for x in accs]} | extra), flush=True)


def _accuracy(model: torch.nn.Module, fg: torch.Tensor, labels: torch.Tensor) -> float:
    return 100.0 * evaluate(model, fg, labels, num_classes=N_CLASSES)["accuracy"]


def finetune(run: Path, out: Path, lr: float) -> None:
    """Fine-tuning: does the fall with the real fraction follow the steps, the yaws or the lr?"""
    braille = _stage(run, "braille")
    base = _stage(run, "classify_sim")
    pool = BrailleSet.load(braille / "finetune.npz")
    test = BrailleSet.load(braille / "classifier_test.npz")
    test_fg = test.foreground("real")
    upright = pool.subset(torch.nonzero(pool.poses.yaw_deg.abs() < 1).squeeze(1))

    def tune(name: str, subset: BrailleSet, lr: float, epochs: int = 4, steps: int = 0) -> None:
        accs = []
        for seed in SEEDS:
            cfg = ClassifierConfig(
                width=16, blocks=(1, 1, 1, 1), batch_size=20, lr=lr, epochs=epochs, seed=seed
            )
            kwargs = QUIET | ({"max_epochs": -1, "max_steps": steps} if steps else {})
            model = train_classifier(
                subset.foreground("real"),
                subset.labels,
                cfg,
                out / f"{name}_seed{seed}",
                loggers=[],
                trainer_kwargs=kwargs,
                num_classes=N_CLASSES,
                init=load_classifier(base / f"model_seed{seed}.pt"),
            )
            accs.append(_accuracy(model, test_fg, test.labels))
        _report(name, accs, n=len(subset), lr=lr, epochs=epochs, steps=steps or None)

    def fraction(pairs: BrailleSet, f: float) -> BrailleSet:
        return pairs.subset(stratified_subset(pairs.labels, f, 0))  # the recipe seed, 0

    steps_at_20 = -(-len(fraction(pool, 0.2)) // 20) * 4  # the 20% row's optimiser steps
    for f in (0.2, 0.8, 1.0):
        tune(f"all yaws {f:.0%}", fraction(pool, f), lr)
    for f in (0.2, 0.8, 1.0):
        tune(f"all yaws {f:.0%}, {steps_at_20} steps", fraction(pool, f), lr, steps=steps_at_20)
    for f in (0.2, 0.8, 1.0):
        tune(f"upright only {f:.0%}", fraction(upright, f), lr)
    other = 1e-3 if lr < 1e-3 else 1e-4
    for f in (0.2, 0.8, 1.0):
        tune(f"all yaws {f:.0%}, lr {other:g}", fraction(pool, f), other)


def _images(run: Path, stage: str) -> tuple[torch.Tensor, torch.Tensor]:
    arrays = np.load(_stage(run, stage) / "classifier.npz")
    images = torch.from_numpy(arrays["images"]).float()
    background = torch.from_numpy(arrays["background"]).float()
    return image_to_foreground(images, background), torch.from_numpy(arrays["labels"])


def _cgan_inputs(
    run: Path,
) -> tuple[tuple[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor], torch.Tensor]:
    """The cGAN row's (training foregrounds, labels), the real classifier test set's
    (foregrounds, labels) and the unlabeled real fine-tuning pool's foregrounds."""
    braille = _stage(run, "braille")
    test = BrailleSet.load(braille / "classifier_test.npz")
    pool_fg = BrailleSet.load(braille / "finetune.npz").foreground("real")
    return _images(run, cgan_stage), (test.foreground("real"), test.labels), pool_fg


def _fitted_translator(run: Path, fit_stage: str, name: str, **settings: object) -> Any:
    """The translator ``fit_stage`` fitted, with the inference settings its row's translate
    stage used (e.g. 2 sampler steps) and ``settings`` on top."""
    translator = translator_class(name).load(_stage(run, fit_stage) / "translator.pt")
    done = json.loads((_stage(run, f"translate_{name}") / "_done.json").read_text())
    overrides = (done["config"].get("translator_config") or {}) | settings
    if overrides:
        translator.config = translator.parse_config(translator.config.model_dump() | overrides)
    return translator


def cgan(run: Path, out: Path) -> None:
    """cGAN row: train the base classifier on its images as they are and with one change."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = BrailleSet.load(_stage(run, "braille") / "classifier.npz")
    real_fg = classifier_set.foreground("real")
    contact = (classifier_set.depth > 0).expand(-1, 3, -1, -1)

    def contrast(x: torch.Tensor) -> float:
        return float((x - 0.5)[contact].abs().mean() * 255)

    def nyquist_power(x: torch.Tensor) -> float:
        spectrum = torch.fft.fft2((x - x.mean((-2, -1), keepdim=True)) * 255).abs().pow(2)
        mid = x.shape[-1] // 2
        return float(spectrum[..., mid, :].mean() + spectrum[..., :, mid].mean()) / x[0, 0].numel()

    print(
        json.dumps(
            {
                "contact contrast (grey levels)": {"cgan": contrast(fg), "real": contrast(real_fg)},
                "power at the Nyquist rows and columns": {
                    "cgan": nyquist_power(fg[::10]),
                    "real": nyquist_power(real_fg[::10]),
                },
                "pixel noise (foreground units)": {
                    "cgan": estimate_pixel_noise(fg).tolist(),
                    "real": estimate_pixel_noise(pool_fg).tolist(),
                },
            }
        ),
        flush=True,
    )

    def notch(x: torch.Tensor) -> torch.Tensor:  # only the period-2 (checkerboard) content
        spectrum = torch.fft.fft2(x)
        mid = x.shape[-1] // 2
        spectrum[..., mid, :] = 0
        spectrum[..., :, mid] = 0
        return torch.fft.ifft2(spectrum).real

    def rescaled(x: torch.Tensor) -> torch.Tensor:  # contact contrast scaled to real's
        return 0.5 + (x - 0.5) * (contrast(real_fg) / contrast(fg))

    conditions: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
        "cgan as translated": lambda x: x,
        "cgan, checkerboard notched out": notch,
        "cgan, contrast scaled to real": rescaled,
    }
    for name, change in conditions.items():
        _train_and_score(name, (change(fg), labels), test, pool_fg, out)


def _base_classifier(
    fg: torch.Tensor, labels: torch.Tensor, seed: int, folder: Path
) -> torch.nn.Module:
    """The A/B protocol's base classifier (table1.yaml's, 4 epochs) trained on ``fg``."""
    cfg = ClassifierConfig(
        width=16, blocks=(1, 1, 1, 1), batch_size=64, lr=0.002, epochs=4, seed=seed
    )
    return train_classifier(
        fg, labels, cfg, folder, loggers=[], trainer_kwargs=QUIET, num_classes=N_CLASSES
    )


def _train_and_score(
    name: str,
    train: tuple[torch.Tensor, torch.Tensor],
    test: tuple[torch.Tensor, torch.Tensor],
    pool_fg: torch.Tensor,
    out: Path,
) -> None:
    """The base classifier of table1.yaml trained on ``train`` (seeds 0, 1, 2), scored on
    ``test``, and again with BatchNorm statistics from the unlabeled real pool."""
    (train_fg, labels), (test_fg, test_labels) = train, test
    accs, adapted = [], []
    for seed in SEEDS:
        keep, _ = stratified_split(labels, 0.1, seed)
        model = _base_classifier(train_fg[keep], labels[keep], seed, out / f"{name}_seed{seed}")
        accs.append(_accuracy(model, test_fg, test_labels))
        # BatchNorm statistics from unlabeled real frames (the fine-tuning pool): how much
        # of the failure is a shift of feature statistics
        model = copy.deepcopy(model)
        recalibrate_batchnorm(model, pool_fg[torch.randperm(len(pool_fg))[:1024]])
        adapted.append(_accuracy(model, test_fg, test_labels))
    _report(name, accs, bn_on_real_pool=round(float(np.mean(adapted)), 2))


def _low_pass(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """What is coarser than a Gaussian of ``sigma_px`` (kernel to 3 sigma): the coarse band."""
    radius = int(math.ceil(3 * sigma_px))
    return gaussian_blur2d(x, (2 * radius + 1,) * 2, (sigma_px, sigma_px), "reflect")


def _classifier_set_in_order(run: Path, labels: torch.Tensor) -> BrailleSet:
    """The braille stage's classifier set, whose real frames pair image by image with the
    cGAN's translations of it (checked by their labels)."""
    classifier_set = BrailleSet.load(_stage(run, "braille") / "classifier.npz")
    if not torch.equal(classifier_set.labels, labels):
        raise SystemExit(f"{cgan_stage}'s classifier images are not in the braille set's order")
    return classifier_set


def _near_contact(depth: torch.Tensor, px: int = 4) -> torch.Tensor:
    """(N, 1, H, W) True within ``px`` pixels of a pressed pixel."""
    return F.max_pool2d((depth > 0).float(), 2 * px + 1, 1, px) > 0


def cgan_lowpass(run: Path, out: Path, sigma_px: float = 1.0) -> None:
    """cGAN row with the fine detail removed from every image it is trained and tested on:
    if the cGAN's classifiers read its high-frequency artefacts (label-correlated, absent in
    real frames), removing them from both sides lifts the accuracy on real."""
    (fg, labels), (test_fg, test_labels), pool_fg = _cgan_inputs(run)

    pairs = {
        "cgan as translated": (fg, test_fg, pool_fg),
        f"cgan, both sides low-passed (Gaussian sigma {sigma_px} px)": (
            _low_pass(fg, sigma_px),
            _low_pass(test_fg, sigma_px),
            _low_pass(pool_fg, sigma_px),
        ),
    }
    for name, (train_fg, test_side, pool_side) in pairs.items():
        _train_and_score(name, (train_fg, labels), (test_side, test_labels), pool_side, out)


def cgan_bands(run: Path, out: Path, sigma_px: float = 1.0) -> None:
    """cGAN row with its images' coarse and fine detail swapped, band by band, with the real
    frames of the same classifier contacts: which band carries what fails on real. Each
    condition keeps one band of the cGAN image and takes the other from real (Gaussian
    sigma_px split); the test set is real, unchanged."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")

    cgan_low, real_low = _low_pass(fg, sigma_px), _low_pass(real_fg, sigma_px)
    conditions = {
        f"real's coarse + cGAN's fine detail (split at sigma {sigma_px} px)": real_low
        + (fg - cgan_low),
        f"cGAN's coarse + real's fine detail (split at sigma {sigma_px} px)": cgan_low
        + (real_fg - real_low),
    }
    for name, images in conditions.items():
        _train_and_score(name, (images, labels), test, pool_fg, out)


def cgan_three_bands(run: Path, out: Path, fine_px: float = 1.0, coarse_px: float = 4.0) -> None:
    """cGAN row with one of three bands of its images in real frames otherwise: the middle
    band (detail between Gaussian sigma ``fine_px`` and ``coarse_px``: the dots' shape and
    place) or the coarse band (beyond ``coarse_px``: shading across the view, colour casts).
    Real's fine band in both, so the cGAN's fine-detail pattern is out of play."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")

    def bands(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        low_fine, low_coarse = _low_pass(x, fine_px), _low_pass(x, coarse_px)
        return x - low_fine, low_fine - low_coarse, low_coarse

    (_, cgan_mid, cgan_coarse), (real_fine, real_mid, real_coarse) = bands(fg), bands(real_fg)
    at = f"(split at sigma {fine_px} / {coarse_px} px)"
    conditions = {
        f"real's fine + cGAN's middle + real's coarse {at}": real_fine + cgan_mid + real_coarse,
        f"real's fine + real's middle + cGAN's coarse {at}": real_fine + real_mid + cgan_coarse,
    }
    for name, images in conditions.items():
        _train_and_score(name, (images, labels), test, pool_fg, out)


def cgan_coarse_gain(run: Path, out: Path, coarse_px: float = 4.0) -> None:
    """Is the cGAN's coarse band (beyond Gaussian sigma ``coarse_px``) wrong in strength or
    in shape? Its departure from the no-contact level is weaker than real's (RMS ratio k,
    measured here). Real frames with their coarse band scaled by k, and real's fine and
    middle bands over the cGAN's coarse band scaled by 1 / k: if strength is the cue, the
    first fails as the cGAN's coarse band does and the second recovers."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")
    level = 0.5  # a foreground's no-contact level (image - background + 0.5)
    cgan_coarse = _low_pass(fg, coarse_px) - level
    del fg
    real_coarse = _low_pass(real_fg, coarse_px) - level
    real_detail = real_fg - level - real_coarse
    del real_fg
    k = float(cgan_coarse.pow(2).mean().sqrt() / real_coarse.pow(2).mean().sqrt())
    print(json.dumps({"coarse_rms_ratio_cgan_to_real": round(k, 4)}))
    conditions = {
        f"real, its coarse band (sigma {coarse_px} px) scaled by k = {k:.3f}": (
            lambda: level + real_detail + k * real_coarse
        ),
        f"real's finer bands + cGAN's coarse band scaled by 1 / k (sigma {coarse_px} px)": (
            lambda: level + real_detail + cgan_coarse / k
        ),
    }
    for name, images in conditions.items():
        _train_and_score(name, (images(), labels), test, pool_fg, out)


def cgan_coarse_where(run: Path, coarse_px: float = 4.0, n: int = 2000) -> None:
    """Measurements only, on the first ``n`` classifier images: where the cGAN's coarse band
    (beyond Gaussian sigma ``coarse_px``) departs from real's (within 4 px of the contact or
    away from it), and how much of that the best whole-pixel shift of each image (within
    3 px) removes, i.e. how much of it is a misregistration."""
    (fg, labels), _, _ = _cgan_inputs(run)
    classifier_set = BrailleSet.load(_stage(run, "braille") / "classifier.npz")
    fg, real = fg[:n], classifier_set.foreground("real")[:n]
    cgan_coarse, real_coarse = _low_pass(fg, coarse_px), _low_pass(real, coarse_px)
    diff = (cgan_coarse - real_coarse) * 255
    near = _near_contact(classifier_set.depth[:n])
    near = near.expand(-1, 3, -1, -1)
    grey_cgan, grey_real = cgan_coarse.mean(1, keepdim=True), real_coarse.mean(1, keepdim=True)
    shifts = [(dy, dx) for dy in range(-3, 4) for dx in range(-3, 4)]
    errors = torch.stack(
        [(torch.roll(grey_cgan, s, (2, 3)) - grey_real).pow(2).mean(dim=(1, 2, 3)) for s in shifts],
        1,
    )
    unshifted = errors[:, shifts.index((0, 0))].mean()
    row = {
        "coarse_diff_rms_near_contact": float(diff[near].pow(2).mean().sqrt()),
        "coarse_diff_rms_away": float(diff[~near].pow(2).mean().sqrt()),
        "share_of_pixels_near": float(near.float().mean()),
        "best_shift_lowers_squared_diff_by": float(1 - errors.min(1).values.mean() / unshifted),
        "share_of_images_best_unshifted": float(
            (errors.argmin(1) == shifts.index((0, 0))).float().mean()
        ),
    }
    print(json.dumps({k: round(v, 4) for k, v in row.items()}))


def cgan_coarse_place(run: Path, out: Path, coarse_px: float = 4.0) -> None:
    """Where the cGAN's coarse cue sits: real frames with the cGAN's coarse band (beyond
    Gaussian sigma ``coarse_px``) put in place of real's only within 4 px of the contact,
    and only away from it (a hard mask; the two conditions add up to the whole band)."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")
    swap = _low_pass(fg, coarse_px) - _low_pass(real_fg, coarse_px)
    del fg
    near = _near_contact(classifier_set.depth)
    conditions = {
        f"real + the cGAN's coarse band (sigma {coarse_px} px) within 4 px of the contact": near,
        f"real + the cGAN's coarse band (sigma {coarse_px} px) away from the contact": ~near,
    }
    for name, where in conditions.items():
        _train_and_score(name, (real_fg + swap * where, labels), test, pool_fg, out)


def cgan_away_pattern(run: Path, out: Path, coarse_px: float = 4.0) -> None:
    """Does the cGAN's coarse difference to real away from the contact (more than 4 px from
    it) carry the character? The base classifier trained on that difference alone (on 0.5
    grey) and scored on held-out images of the same kind (20% of each character). The
    masked-out neighbourhood of the contact outlines the character by itself, so the
    control keeps the mask and replaces the difference by its mean over the masked part."""
    (fg, labels), _, _ = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    swap = _low_pass(fg, coarse_px) - _low_pass(classifier_set.foreground("real"), coarse_px)
    del fg
    away = (~_near_contact(classifier_set.depth)).float()
    level = (swap * away).sum(dim=(2, 3), keepdim=True) / away.sum(dim=(2, 3), keepdim=True)
    conditions = {
        "the character read from the cGAN's coarse difference away from the contact": 0.5
        + swap * away,
        "control: the same mask, the difference replaced by its mean there": 0.5 + level * away,
    }
    for name, pattern in conditions.items():
        accs = []
        for seed in SEEDS:
            keep, held = stratified_split(labels, 0.2, seed)
            folder = out / f"away_pattern_seed{seed}"
            model = _base_classifier(pattern[keep], labels[keep], seed, folder)
            accs.append(_accuracy(model, pattern[held], labels[held]))
        _report(name, accs)


HALO_SIGMAS_PX = (4.0, 8.0, 16.0)


def cgan_halo(run: Path, out: Path, coarse_px: float = 4.0) -> None:
    """Is the cGAN's coarse difference to real away from the contact a halo: its own contact
    colour change spread wider than real's? Per channel, least squares of that difference on
    the cGAN's near-contact colour change blurred at 4, 8 and 16 px (plus a constant), over
    every pixel away from the contact; prints the share of its variance the fit explains,
    then trains on real + the fitted halo only and on real + what the fit leaves only."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")
    swap = _low_pass(fg, coarse_px) - _low_pass(real_fg, coarse_px)
    near = _near_contact(classifier_set.depth)
    contact = fg * near
    del fg
    away = (~near).float()
    halo = torch.zeros_like(swap)
    explained = []
    for c in range(swap.shape[1]):
        columns = [_low_pass(contact[:, c : c + 1], s).flatten() for s in HALO_SIGMAS_PX]
        design = torch.stack([*columns, torch.ones_like(columns[0])], dim=1).double()
        target, weight = swap[:, c].flatten().double(), away.flatten().double()
        coef = torch.linalg.lstsq(design * weight[:, None], target * weight).solution
        prediction = design @ coef
        halo[:, c] = prediction.float().view_as(swap[:, c])
        resid = (target - prediction) * weight
        centred = (target - (target * weight).sum() / weight.sum()) * weight
        explained.append(
            {
                "channel": "rgb"[c],
                "coef_per_sigma_px": dict(zip(HALO_SIGMAS_PX, coef[:-1].tolist(), strict=True)),
                "r2_away": round(1 - float(resid.square().sum() / centred.square().sum()), 4),
            }
        )
    print(json.dumps({"halo_fit": explained}))
    del contact
    conditions = {
        "real + the halo fitted to the cGAN's coarse band away from the contact": halo,
        "real + what that halo fit leaves of the cGAN's coarse band away from it": swap - halo,
    }
    for name, part in conditions.items():
        _train_and_score(name, (real_fg + part * away, labels), test, pool_fg, out)


def cgan_mean_colour(run: Path, out: Path) -> None:
    """Real frames shifted by the cGAN's per-image mean colour offset (its image's mean over
    the view, channel by channel, less real's): whether the coarse cue away from the
    contact is a global colour offset that follows the character."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    classifier_set = _classifier_set_in_order(run, labels)
    real_fg = classifier_set.foreground("real")
    offset = fg.mean(dim=(2, 3), keepdim=True) - real_fg.mean(dim=(2, 3), keepdim=True)
    del fg
    print(
        json.dumps({"offset_rms_grey_levels": round(float(offset.pow(2).mean().sqrt() * 255), 3)})
    )
    name = "real + the cGAN's per-image mean colour offset"
    _train_and_score(name, (real_fg + offset, labels), test, pool_fg, out)


def cgan_noise(run: Path, out: Path) -> None:
    """cGAN row with camera noise drawn into its training images as the diffusion translator
    draws it into its samples (per channel, the level ``estimate_pixel_noise`` measures on
    the real fine-tuning pool; one fixed draw an image, seeded): the one thing the two
    translators' images differ in by construction (the cGAN draws nothing at inference)."""
    (fg, labels), test, pool_fg = _cgan_inputs(run)
    std = estimate_pixel_noise(pool_fg)
    draw = torch.randn(fg.shape, generator=torch.Generator().manual_seed(0))
    noisy = fg + draw * std.view(1, -1, 1, 1)
    print(json.dumps({"noise_std_foreground_units": [round(float(v), 5) for v in std]}))
    _train_and_score("cgan + the diffusion's camera noise", (noisy, labels), test, pool_fg, out)


def rotated(run: Path) -> None:
    """Every classify stage's models on the paired test set (yaws to 90 deg) and its yaw-0 part."""
    test = BrailleSet.load(_stage(run, "braille") / "test.npz")
    fg = test.foreground("real")
    up = test.poses.yaw_deg.abs() < 1
    for stage in sorted(p.name.rsplit("-", 1)[0] for p in run.glob("classify_*-*")):
        models = [load_classifier(_stage(run, stage) / f"model_seed{s}.pt") for s in SEEDS]
        _report(
            stage,
            [_accuracy(m, fg, test.labels) for m in models],
            upright_part=round(
                float(np.mean([_accuracy(m, fg[up], test.labels[up]) for m in models])), 2
            ),
        )


#: (fit stage, translator) of the rows whose translator the run fitted
FITTED = (
    ("fit_cgan", "cgan"),
    ("finetune_diffusion", "diffusion"),
    ("fit_calibrated", "calibrated"),
)


def legibility(run: Path) -> None:
    """Every row's models on the classifier test contacts as real, sim and each fitted
    translator render them. A row's accuracy on its own translator's rendering of the test
    contacts, against its accuracy on real: whether its failure on real is the translator's
    appearance (the same contacts, rendered) or the contacts (the test's poses); and the Real
    row's accuracy on a rendering: whether the translator's images carry the characters."""
    test = BrailleSet.load(_stage(run, "braille") / "classifier_test.npz")
    background = test.real_background.float()
    renderings = {"real": test.foreground("real"), "sim": test.foreground("sim")}
    for fit_stage, name in FITTED:
        translator = _fitted_translator(run, fit_stage, name)
        images = translator.translate(test.depth, background, torch.Generator().manual_seed(0))
        renderings[name] = image_to_foreground(to_uint8(images).float(), background)
    rows = ("real", "sim", "cgan", "diffusion", "calibrated")
    for stage in (f"classify_{row}" for row in rows):  # every seed the run trained
        models = [load_classifier(p) for p in sorted(_stage(run, stage).glob("model_seed*.pt"))]
        scores = {k: [_accuracy(m, x, test.labels) for m in models] for k, x in renderings.items()}
        print(
            json.dumps(
                {"row": stage}
                | {k: round(float(np.mean(v)), 2) for k, v in scores.items()}
                | {"per_seed": {k: [round(x, 2) for x in v] for k, v in scores.items()}}
            ),
            flush=True,
        )


def _similarity(images: torch.Tensor, real: torch.Tensor, contact: torch.Tensor) -> dict:
    """SSIM (torchmetrics' map, as the table's) and MSE, whole frame, contact, the rest."""
    _, ssim_map = structural_similarity_index_measure(
        images.float(), real, data_range=255.0, return_full_image=True
    )
    per_pixel = {"ssim": ssim_map.mean(1), "mse": (images.float() - real).square().mean(1)}
    return {
        f"{metric}_{part}": round(float(values[mask].mean()), 4)
        for metric, values in per_pixel.items()
        for part, mask in (
            ("all", torch.ones_like(contact)),
            ("contact", contact),
            ("rest", ~contact),
        )
    }


def ssim(run: Path) -> None:
    """Where the table's SSIM and MSE against real come from: each translate stage's test
    images scored on the contact (depth > 0.01 mm, grown by 3 px) and off it; then the
    diffusion translator again with and without the camera noise it adds (one change)."""
    test = BrailleSet.load(_stage(run, "braille") / "test.npz")
    real = test.real.float()
    contact = F.max_pool2d((test.depth > 0.01).float(), 7, 1, 3)[:, 0] > 0
    print(json.dumps({"contact_share": round(float(contact.float().mean()), 3)}), flush=True)
    for stage in (
        "translate_sim",
        "translate_aug",
        "translate_cgan",
        "translate_diffusion",
        "translate_calibrated",
    ):
        images = torch.from_numpy(np.load(_stage(run, stage) / "test.npz")["images"])
        print(json.dumps({"stage": stage} | _similarity(images, real, contact)), flush=True)
    for noise in (True, False):
        translator = _fitted_translator(
            run, "finetune_diffusion", "diffusion", observation_noise=noise
        )
        images = translator.translate(
            test.depth, test.real_background.float(), torch.Generator().manual_seed(0)
        )
        print(
            json.dumps(
                {"stage": f"diffusion, observation_noise={noise}"}
                | _similarity(to_uint8(images), real, contact)
            ),
            flush=True,
        )


def footprint(run: Path) -> None:
    """How each rendering of the same test contacts draws a contact, against real: contact
    contrast (mean |foreground| where the depth presses, grey levels), the share of the
    change drawn past the pressed pixels (what the gel's elastic spread puts there, above the
    frame's own noise), and the share of the contact's change finer than ~2 px (what a
    Gaussian of sigma 1 px removes). Measurements only: which of them differ from real."""
    test = BrailleSet.load(_stage(run, "braille") / "test.npz")
    pressed = (test.depth > 0.01).expand(-1, 3, -1, -1)
    near = F.max_pool2d(pressed.float(), 15, 1, 7) > 0  # within 7 px of a pressed pixel
    renderings = {"real": test.real}
    for row in ("sim", "cgan", "diffusion", "calibrated"):
        renderings[row] = torch.from_numpy(
            np.load(_stage(run, f"translate_{row}") / "test.npz")["images"]
        )
    background = test.real_background.float()
    for name, images in renderings.items():
        fg = (image_to_foreground(images.float(), background) - 0.5) * 255
        centred = fg - fg.mean((-2, -1), keepdim=True)
        far_var = float(centred[~near].pow(2).mean())  # the frame's own noise, away from contacts
        energy = fg.pow(2)
        past = near & ~pressed
        spread = float(energy[past].sum() - far_var * past.sum()) / float(
            energy[near].sum() - far_var * near.sum()
        )
        fine = fg - gaussian_blur2d(fg, (7, 7), (1.0, 1.0), "reflect")
        print(
            json.dumps(
                {
                    "rendering": name,
                    "contact_contrast": round(float(fg[pressed].abs().mean()), 2),
                    "share_past_the_pressed_pixels": round(spread, 3),
                    "fine_share_on_contact": round(
                        float(fine[pressed].pow(2).sum() / energy[pressed].sum()), 3
                    ),
                    "noise_grey": round(far_var**0.5, 2),
                }
            ),
            flush=True,
        )


def main() -> None:
    global cgan_stage
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "experiment",
        choices=(
            "finetune",
            "cgan",
            "cgan_lowpass",
            "cgan_noise",
            "cgan_bands",
            "cgan_three_bands",
            "cgan_coarse_gain",
            "cgan_coarse_where",
            "cgan_coarse_place",
            "cgan_mean_colour",
            "cgan_away_pattern",
            "cgan_halo",
            "rotated",
            "legibility",
            "ssim",
            "footprint",
        ),
    )
    parser.add_argument("run_dir", type=Path, help="a finished table1.yaml run directory")
    parser.add_argument("--out", type=Path, default=None, help="scratch folder (default: temp)")
    parser.add_argument("--lr", type=float, default=1e-4, help="fine-tuning lr (table1.yaml's)")
    parser.add_argument(
        "--sigma", type=float, default=1.0, help="band split, Gaussian px (cgan_lowpass/_bands)"
    )
    parser.add_argument(
        "--coarse",
        type=float,
        default=4.0,
        help="coarse split, px (cgan_three_bands, _coarse_gain)",
    )
    parser.add_argument(
        "--cgan-stage",
        default=cgan_stage,
        help="translate stage the cgan_* experiments read (e.g. translate_cgan_bn of "
        "scripts/cgan_generator_ab.yaml)",
    )
    ns = parser.parse_args()
    cgan_stage = ns.cgan_stage
    with tempfile.TemporaryDirectory() as tmp:
        out = ns.out or Path(tmp)
        experiments: dict[str, Callable[[], None]] = {
            "finetune": lambda: finetune(ns.run_dir, out, ns.lr),
            "cgan": lambda: cgan(ns.run_dir, out),
            "cgan_lowpass": lambda: cgan_lowpass(ns.run_dir, out, ns.sigma),
            "cgan_noise": lambda: cgan_noise(ns.run_dir, out),
            "cgan_bands": lambda: cgan_bands(ns.run_dir, out, ns.sigma),
            "cgan_three_bands": lambda: cgan_three_bands(ns.run_dir, out, ns.sigma, ns.coarse),
            "cgan_coarse_gain": lambda: cgan_coarse_gain(ns.run_dir, out, ns.coarse),
            "cgan_coarse_where": lambda: cgan_coarse_where(ns.run_dir, ns.coarse),
            "cgan_coarse_place": lambda: cgan_coarse_place(ns.run_dir, out, ns.coarse),
            "cgan_mean_colour": lambda: cgan_mean_colour(ns.run_dir, out),
            "cgan_away_pattern": lambda: cgan_away_pattern(ns.run_dir, out, ns.coarse),
            "cgan_halo": lambda: cgan_halo(ns.run_dir, out, ns.coarse),
            "rotated": lambda: rotated(ns.run_dir),
            "legibility": lambda: legibility(ns.run_dir),
            "ssim": lambda: ssim(ns.run_dir),
            "footprint": lambda: footprint(ns.run_dir),
        }
        experiments[ns.experiment]()


if __name__ == "__main__":
    main()
