"""How far the gap shrinks once the selected effects are added to the simulator.

On the held-out split, three views of the same question:

- **pixel**: SSIM and MSE (0..255) of sim vs real, and of sim + effects vs real, pair by pair;
- **distribution**: KID between real and sim (+ effects) images in the features of the
  project's own encoder (``metrics.fit_encoder``), trained on the *fit* split's real images;
- **downstream**: a small classifier trained on the fit split's plain sim images and one on
  sim + effects, both tested on the held-out real images (and, for scale, one trained on the
  fit split's real images). Skipped, with the reason, when labels are missing or fewer than
  two classes are present.

Classifiers see foregrounds ``(image - no-contact frame) / 255 + 0.5`` as everywhere in the
project: plain sim over its own frame, sim + effects over the candidate simulator's rendering
of the no-contact frame, real over the measured one.

Pixel noise: zero-mean noise never lowers a paired gap, so the selection never adds camera
noise, and a sim (+ effects) that is cleaner than the real frames trains a classifier that
reads noisy frames near chance (docs/results/diagnosis_settings.md). Each training set's
per-channel noise is estimated frame to frame (``metrics.estimate_pixel_noise``, as the
diffusion translator does) and so is that of the fit split's real frames; a set cleaner than
real gets white Gaussian noise up to the real level, in ``NOISE_COPIES`` seeded copies.
Estimated from the paired data only; reported under ``downstream.noise``. A set noisier than
real is left as it is.
"""

from __future__ import annotations

import logging
import math
import tempfile
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import torch

from tactile_bench.data.pixels import image_to_foreground
from tactile_bench.diagnose.breakdown import DOWNSTREAM, KID
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.scene import fit_reference, make_scene
from tactile_bench.diagnose.simulate import apply_effects, render_background
from tactile_bench.errors import TactileBenchError
from tactile_bench.metrics import estimate_pixel_noise, fit_encoder, kid, ssim_mse
from tactile_bench.sensor.timing import timed_span

# KID only compares sets in the encoder's features: a short training keeps the before/after
# order of a 300-pair export for half the time of a long one (docs/results/diagnosis_settings.md)
ENCODER_STEPS = 150
# training images seen per classifier (epochs = this / training images): with a few images a
# class, only long training with random shifts generalises at all (the same page)
CLASSIFIER_SAMPLES = 15000
MAX_EPOCHS = 60
# random shifts up to this share of the image size: braille contacts vary by +-3 mm, about
# +-10 px at 64 px
SHIFT_FRACTION = 6 / 64
NOISE_TRAIN_IMAGES = 2000  # noise-matched copies: about this many training images a set
NOISE_COPIES = 8  # ... and at most this many copies of each image


@dataclass(frozen=True)
class Skipped:
    """A part of the answer not computed, and why."""

    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"skipped": self.reason}


@dataclass
class KidScores:
    """KID of sim and sim + effects against real, in the project encoder's features."""

    kid_before: float
    kid_after: float
    kid_before_std: float
    kid_after_std: float
    encoder: str

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Downstream:
    """Held-out real accuracy of classifiers trained on plain sim, sim + effects and real."""

    classes: int
    n_train: int
    n_test: int
    epochs: int
    classifier: str
    noise: dict[str, Any]  # the noise treatment, each training set's noise and what was added
    plain_sim_accuracy: float = math.nan
    sim_plus_effects_accuracy: float = math.nan
    real_accuracy: float = math.nan

    @property
    def accuracies(self) -> dict[str, float]:
        """Each training source's accuracy: plain_sim, sim_plus_effects, real."""
        return {
            "plain_sim": self.plain_sim_accuracy,
            "sim_plus_effects": self.sim_plus_effects_accuracy,
            "real": self.real_accuracy,
        }

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class HowFar:
    """The held-out gap before and after adding the selected effects, three ways."""

    effects: dict[str, dict[str, float]]
    pixel_before: dict[str, float]
    pixel_after: dict[str, float]
    distribution: KidScores | Skipped
    downstream: Downstream | Skipped

    def to_dict(self) -> dict[str, Any]:
        return {
            "effects": self.effects,
            "pixel": {"before": self.pixel_before, "after": self.pixel_after},
            "distribution": self.distribution.to_dict(),
            "downstream": self.downstream.to_dict(),
        }


def _foreground(images: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    return image_to_foreground(images.float(), background.float())


def match_noise(
    x: torch.Tensor, target_std: torch.Tensor, copies: int, seed: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``copies`` noisy copies (copies * N, C, S, S) of foregrounds ``x`` whose estimated
    per-channel pixel noise is raised to ``target_std`` (C,) where it is below it, the
    estimate of ``x`` and the std added (both (C,)): white Gaussian noise, seeded."""
    own = estimate_pixel_noise(x)
    if own is None:  # too few frames to tell how noisy they are: nothing added
        own = torch.full((x.shape[1],), math.nan)
        added = torch.zeros(x.shape[1])
    else:
        added = (target_std.square() - own.square()).clamp(min=0.0).sqrt()
    if not bool((added > 0).any()):  # as noisy as real or noisier: plain copies, no draws
        return x.repeat(copies, 1, 1, 1), own, added
    gen = torch.Generator().manual_seed(seed)
    scale = added[None, :, None, None]
    out = torch.cat([x + scale * torch.randn(x.shape, generator=gen) for _ in range(copies)])
    return out, own, added


@dataclass
class _Classifiers:
    """What every downstream classifier shares: the labels, the held-out real test set, the
    training config and the real frames' pixel noise each training set is matched to."""

    classes: list[str]
    y_train: torch.Tensor
    test: torch.Tensor
    y_test: torch.Tensor
    config: Any  # classify.ClassifierConfig (imported only when classifiers train)
    real_std: torch.Tensor | None
    copies: int


def _classifiers(
    data: DiagnosisPairs, fit_idx: torch.Tensor, held_idx: torch.Tensor, seed: int
) -> _Classifiers | Skipped:
    from tactile_bench.classify import ClassifierConfig

    fit_labels = [data.labels[i] for i in fit_idx.tolist()]
    held_labels = [data.labels[i] for i in held_idx.tolist()]
    if any(label == "" for label in fit_labels + held_labels):
        return Skipped("unlabelled pairs: no downstream classifier")
    classes = sorted(set(fit_labels))
    if len(classes) < 2:
        return Skipped(f"fewer than 2 classes in the fit split ({len(classes)})")
    index = {c: i for i, c in enumerate(classes)}
    known = [i for i, label in enumerate(held_labels) if label in index]
    if not known:
        return Skipped("no held-out pair has a class seen in the fit split")
    real_std = estimate_pixel_noise(_foreground(data.real[fit_idx], data.background))
    copies = 1 if real_std is None else min(NOISE_COPIES, -(-NOISE_TRAIN_IMAGES // len(fit_idx)))
    epochs = min(MAX_EPOCHS, max(2, round(CLASSIFIER_SAMPLES / (len(fit_idx) * copies))))
    shift = max(1, round(SHIFT_FRACTION * data.size))
    return _Classifiers(
        classes=classes,
        y_train=torch.tensor([index[c] for c in fit_labels]).repeat(copies),
        test=_foreground(data.real[held_idx[known]], data.background),
        y_test=torch.tensor([index[held_labels[i]] for i in known]),
        config=ClassifierConfig(
            width=8, blocks=(1, 1, 1, 1), epochs=epochs, augment=True, shift_px=shift, seed=seed
        ),
        real_std=real_std,
        copies=copies,
    )


def _accuracies(
    setup: _Classifiers, sets: Mapping[str, torch.Tensor], seed: int
) -> dict[str, tuple[float, dict[str, list[float]] | None]]:
    """Held-out real accuracy of a classifier trained on each set of foregrounds (noise
    matched to the real frames'), and the noise each had and was given. One seed on
    several sets: trained as one stacked model (``classify.train_classifiers``), each
    member as it would train alone (its initial weights, batches and shifts)."""
    from tactile_bench.classify import evaluate

    noises: dict[str, dict[str, list[float]] | None] = {}
    inputs: dict[str, torch.Tensor] = {}
    for source, x in sets.items():
        noises[source] = None
        if setup.real_std is not None:
            x, own, added = match_noise(x, setup.real_std, setup.copies, seed)
            noises[source] = {"std": (255 * own).tolist(), "added": (255 * added).tolist()}
        inputs[source] = x
    with timed_span(DOWNSTREAM):
        models = _train(setup, list(inputs.values()))
    n_classes = len(setup.classes)
    return {
        source: (evaluate(model, setup.test, setup.y_test, num_classes=n_classes)["accuracy"],
                 noises[source])
        for source, model in zip(inputs, models, strict=True)
    }  # fmt: skip


def _train(setup: _Classifiers, inputs: list[torch.Tensor]) -> list[Any]:
    """One classifier of ``setup.config`` on each of ``inputs`` (same labels), batched."""
    from tactile_bench.classify.train import train_classifiers

    quiet = {"enable_checkpointing": False, "enable_progress_bar": False}
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    n = len(inputs[0])
    rows = [torch.arange(n, device=inputs[0].device) + k * n for k in range(len(inputs))]
    with tempfile.TemporaryDirectory() as tmp:
        return train_classifiers(
            torch.cat(inputs), setup.y_train.repeat(len(inputs)), [setup.config] * len(inputs),
            tmp, loggers=[], trainer_kwargs=quiet, num_classes=len(setup.classes), subsets=rows,
        )  # fmt: skip


def _sim_plus(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    effects: Mapping[str, Mapping[str, float]],
    seed: int,
) -> torch.Tensor:
    """Foregrounds of the fit split's sim + ``effects`` over the candidate simulator's own
    rendering of the no-contact frame."""
    scene = make_scene(data, fit_idx, fit_reference(data, fit_idx))
    images = apply_effects(data, effects, fit_idx, seed, fit_idx)
    return _foreground(images, render_background(scene, effects))


def _downstream(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    effects: Mapping[str, Mapping[str, float]],
    seed: int,
) -> Downstream | Skipped:
    setup = _classifiers(data, fit_idx, held_idx, seed)
    if isinstance(setup, Skipped):
        return setup
    sim_bg = make_scene(data, fit_idx).sim_frame[0]  # the sim's own no-contact frame
    train_sets = {
        "plain_sim": _foreground(data.sim[fit_idx], sim_bg),
        "sim_plus_effects": _sim_plus(data, fit_idx, effects, seed),
        "real": _foreground(data.real[fit_idx], data.background),
    }
    shift = setup.config.shift_px
    out = Downstream(
        classes=len(setup.classes),
        n_train=len(fit_idx),
        n_test=len(setup.y_test),
        epochs=setup.config.epochs,
        classifier=f"ResNet topology, width 8, blocks (1, 1, 1, 1), +-{shift} px shifts, "
        "from scratch",
        noise={"treatment": "none: too few real frames to estimate their pixel noise"},
    )
    if setup.real_std is not None:
        out.noise = {
            "treatment": "per-channel pixel noise of each training set and of the fit split's "
            "real frames estimated frame to frame (deviation from the per-pixel median, "
            "3-sigma clipped); white Gaussian noise added to a set cleaner than real, up to "
            f"the real level, in {setup.copies} seeded copies of every training image",
            "copies": setup.copies,
            "real_std": (255 * setup.real_std).tolist(),
        }
    for source, (accuracy, noise) in _accuracies(setup, train_sets, seed).items():
        if noise is not None:
            out.noise[source] = noise
        setattr(out, f"{source}_accuracy", accuracy)
    return out


def accuracy_with_each(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    coalitions: Mapping[str, Mapping[str, Mapping[str, float]]],
    seed: int = 0,
) -> dict[str, float]:
    """Held-out real accuracy of a classifier trained on the fit split's sim + each of
    ``coalitions`` (name -> effects), as the downstream classifiers are trained."""
    setup = _classifiers(data, fit_idx, held_idx, seed)
    if isinstance(setup, Skipped):
        raise TactileBenchError(f"no downstream classifier: {setup.reason}")
    sets = {name: _sim_plus(data, fit_idx, effects, seed) for name, effects in coalitions.items()}
    return {name: accuracy for name, (accuracy, _) in _accuracies(setup, sets, seed).items()}


def _kid_scores(
    train: torch.Tensor, real: torch.Tensor, sim: torch.Tensor, sim_fx: torch.Tensor, seed: int
) -> KidScores:
    """KID of ``sim`` and ``sim_fx`` against ``real`` in the features of an encoder trained
    on ``train`` (the fit split's real images)."""
    encoder = fit_encoder(train, steps=ENCODER_STEPS, seed=seed)
    f_real, f_sim, f_fx = (encoder.features(x) for x in (real, sim, sim_fx))
    kid_before, std_before = kid(f_sim, f_real, seed=seed)
    kid_after, std_after = kid(f_fx, f_real, seed=seed)
    return KidScores(
        kid_before,
        kid_after,
        std_before,
        std_after,
        f"project autoencoder, {ENCODER_STEPS} steps on the fit split's real",
    )


def how_far(
    data: DiagnosisPairs,
    fit_idx: torch.Tensor,
    held_idx: torch.Tensor,
    effects: Mapping[str, Mapping[str, float]],
    downstream: bool = True,
    seed: int = 0,
    progress: bool = True,
) -> HowFar:
    """Gap before and after adding ``effects``, on the held-out split (module docstring)."""
    fit_idx = torch.as_tensor(fit_idx, dtype=torch.long)
    held_idx = torch.as_tensor(held_idx, dtype=torch.long)
    real, sim = data.real[held_idx].float(), data.sim[held_idx].float()
    sim_fx = apply_effects(data, effects, held_idx, seed, fit_idx)
    distribution: KidScores | Skipped = Skipped("fewer than 2 pairs in a split")
    if len(held_idx) >= 2 and len(fit_idx) >= 2:
        with timed_span(KID):
            distribution = _kid_scores(data.real[fit_idx].float(), real, sim, sim_fx, seed)
    return HowFar(
        effects={k: dict(v) for k, v in effects.items()},
        pixel_before=ssim_mse(sim, real),
        pixel_after=ssim_mse(sim_fx, real),
        distribution=distribution,
        downstream=_downstream(data, fit_idx, held_idx, effects, seed)
        if downstream
        else Skipped("--no-downstream"),
    )
