"""Braille sets from a folder in the Tactile-Diffusion layout, shaped like the simulated ones.

A user with the real braille data points a recipe's ``braille_data`` stage at it
(``source: PATH``, the ``braille`` folder or its parent) and every downstream stage runs
unchanged:

- ``finetune``: every (TACTO depth, real frame) pair of ``real_fine_tuning``: the pool the
  classifiers fine-tune on a fraction of, as ``braille_clf`` draws ``p_data_fine_tune`` of
  all of ``real_fine_tuning/color``; its sim image is our simulator over that depth;
- ``split_train`` / ``test``: the train / test lists of the diffusion translator's split
  (``files_train_test.npy``, or one drawn as ``split_braille_dataset`` does: 20% of the
  files, 80/20), what ``train_braille.py`` / ``test_braille.py`` train and score on;
- ``sim_release`` (``sim_source: release``): the release's TACTO frames ``sim_tacto/color``
  on ``bg_11``, the images the paper's Sim row trained on; no depth (``has_depth`` False);
- ``classifier_test``: the release's ``real/color`` frames, which have no depth: their sim
  image and depth are absent (zeros), and ``has_sim`` says so, so nobody reads them;
- ``classifier``: the simulated classifier grid, which the paper also simulated; it has no
  real images (``has_real`` is False), so the Real row must train on ``finetune`` instead.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.corpus import CorpusPairs
from tactile_bench.data.pixels import to_uint8
from tactile_bench.data.tactile_diffusion import (
    SIM_BACKGROUND_ID,
    Split,
    load_braille_pairs,
    load_braille_real_images,
)
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics

# What each set of a layout-backed run carries (absent parts are zeros of the right shape).
LAYOUT_CONTENT = {
    "finetune": {"has_sim": True, "has_real": True},
    "split_train": {"has_sim": True, "has_real": True},
    "test": {"has_sim": True, "has_real": True},
    "classifier": {"has_sim": True, "has_real": False},
    "classifier_test": {"has_sim": False, "has_real": True},
}
SIM_RELEASE_CONTENT = {"has_sim": True, "has_real": False, "has_depth": False}


def _single(background: torch.Tensor) -> torch.Tensor:
    """The layout has one real no-contact frame; CorpusPairs stacks them (K, 3, S, S)."""
    return background[0] if background.dim() == 4 else background


def _unposed(labels: torch.Tensor, depth: torch.Tensor) -> Poses:
    """The layout has no poses: centred, upright, pressed as deep as the depth image says."""
    n = len(labels)
    zeros = torch.zeros(n)
    press = depth.flatten(1).amax(1) if n else zeros
    return Poses(labels, zeros, zeros, zeros, press)


def _pairs_set(
    pairs: CorpusPairs, sim_background: torch.Tensor, generator: torch.Generator, gel: GelSpec
) -> BrailleSet:
    labels = torch.as_tensor(pairs.meta["label"], dtype=torch.int64)
    sim = SimOptics().render(pairs.depth, sim_background.float(), generator, gel)
    return BrailleSet(
        depth=pairs.depth.float(),
        sim=to_uint8(sim),
        real=to_uint8(pairs.real),
        labels=labels,
        poses=_unposed(labels, pairs.depth),
        sim_background=to_uint8(sim_background),
        real_background=to_uint8(_single(pairs.real_background)),
    )


def _relabel(labels: torch.Tensor, chars: tuple[str, ...], root: Path) -> torch.Tensor:
    """Loader labels index ``CHARACTERS``; the stage's sets index its own ``chars``."""
    position = {CHARACTERS.index(c): i for i, c in enumerate(chars)}
    missing = sorted({CHARACTERS[int(v)] for v in labels.unique()} - set(chars))
    if missing:
        raise TactileBenchError(
            f"source: {root}: has characters {''.join(missing)!r} outside chars={''.join(chars)!r}"
        )
    return torch.tensor([position[int(v)] for v in labels], dtype=torch.int64)


def check_braille_layout(root: Path, sim_release: bool = False) -> None:
    """Fail before any work when ``root`` is not a Tactile-Diffusion braille folder."""
    subs = ["real_fine_tuning/color", "real_fine_tuning/mask", "real/color", "bgs"]
    for sub in subs + (["sim_tacto/color"] if sim_release else []):
        if not (root / sub).is_dir():
            raise TactileBenchError(
                f"source: {root / sub}: folder not found (expected the Tactile-Diffusion "
                "braille layout: real_fine_tuning/{color,mask}, real/color, bgs)"
            )


def _split_part(split: Split, part: str) -> dict[str, list[str]]:
    return {letter: parts[part] for letter, parts in split.items()}


def load_layout_sets(
    root: Path,
    gel: GelSpec,
    sim_background: torch.Tensor,
    simulated_classifier: BrailleSet,
    seed: int,
    chars: tuple[str, ...],
    split: Split,
    sim_release: bool = False,
) -> tuple[dict[str, BrailleSet], np.ndarray]:
    """The sets of a braille_data stage, read from ``root`` (see the module doc), and which
    ``finetune`` pairs the split holds out for testing (a translator fitted on the pool
    leaves them out, so its held-out scores are held out).

    ``split``: the translator's split ({letter: {"train", "test"}}), read or drawn by the
    caller (``tactile_diffusion.split_for_run``).
    """
    check_braille_layout(root, sim_release)
    generator = torch.Generator().manual_seed(seed)
    loaded = {
        "finetune": load_braille_pairs(root, "all", gel),
        "split_train": load_braille_pairs(root, _split_part(split, "train"), gel),
        "test": load_braille_pairs(root, _split_part(split, "test"), gel),
    }
    out: dict[str, BrailleSet] = {}
    for name, pairs in loaded.items():
        out[name] = _pairs_set(pairs, sim_background, generator, gel)
        out[name].labels = out[name].poses.labels = _relabel(out[name].labels, chars, root)
    images, labels, background = load_braille_real_images(root, gel)
    labels = _relabel(labels, chars, root)
    n, size = len(labels), gel.size
    blank_depth = torch.zeros(n, 1, size, size)
    classifier_test = BrailleSet(
        depth=blank_depth,
        sim=torch.zeros(n, 3, size, size, dtype=torch.uint8),
        real=to_uint8(images),
        labels=labels,
        poses=_unposed(labels, blank_depth),
        sim_background=to_uint8(sim_background),
        real_background=to_uint8(_single(background)),
    )
    classifier = BrailleSet(
        depth=simulated_classifier.depth,
        sim=simulated_classifier.sim,
        real=torch.zeros_like(simulated_classifier.sim),
        labels=simulated_classifier.labels,
        poses=simulated_classifier.poses,
        sim_background=simulated_classifier.sim_background,
        real_background=to_uint8(_single(background)),
    )
    out |= {"classifier": classifier, "classifier_test": classifier_test}
    test_files = {f"{letter}/{name}" for letter, parts in split.items() for name in parts["test"]}
    in_test = np.isin(loaded["finetune"].meta["file"], sorted(test_files))
    if sim_release:
        sims, sim_labels, sim_bg = load_braille_real_images(
            root, gel, subset="sim_tacto", background_id=SIM_BACKGROUND_ID
        )
        sim_labels = _relabel(sim_labels, chars, root)
        m = len(sim_labels)
        out["sim_release"] = BrailleSet(
            depth=torch.zeros(m, 1, size, size),
            sim=to_uint8(sims),
            real=torch.zeros(m, 3, size, size, dtype=torch.uint8),
            labels=sim_labels,
            poses=_unposed(sim_labels, torch.zeros(m, 1, size, size)),
            sim_background=to_uint8(_single(sim_bg)),
            real_background=to_uint8(_single(background)),
        )
    return out, in_test
