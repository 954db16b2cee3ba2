"""Braille sets from a folder in the Tactile-Diffusion layout, shaped like the simulated ones.

A user with the real braille data points a recipe's ``braille_data`` stage at it
(``source: PATH``) and every downstream stage runs unchanged:

- ``finetune`` / ``test``: the release's ``real_fine_tuning`` train / test pairs (TACTO depth
  and the real frame); their sim image is our simulator over that depth, as TACTO would
  render it;
- ``classifier_test``: the release's ``real/color`` frames, which have no depth: their sim
  image and depth are absent (zeros), and ``has_sim`` says so, so nobody reads them;
- ``classifier``: the simulated classifier grid, which the paper also simulated; it has no
  real images (``has_real`` is False), so the Real row must train on ``finetune`` instead.
"""

from __future__ import annotations

from pathlib import Path

import torch

from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.images import to_uint8
from tactile_bench.data.pairs import PairSet
from tactile_bench.data.tactile_diffusion import load_braille_pairs, load_braille_real_images
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.optics import SimOptics

# What each set of a layout-backed run carries (absent parts are zeros of the right shape).
LAYOUT_CONTENT = {
    "finetune": {"has_sim": True, "has_real": True},
    "test": {"has_sim": True, "has_real": True},
    "classifier": {"has_sim": True, "has_real": False},
    "classifier_test": {"has_sim": False, "has_real": True},
}


def _single(background: torch.Tensor) -> torch.Tensor:
    """The layout has one real no-contact frame; PairSet stacks them (K, 3, S, S)."""
    return background[0] if background.dim() == 4 else background


def _unposed(labels: torch.Tensor, depth: torch.Tensor) -> Poses:
    """The layout has no poses: centred, upright, pressed as deep as the depth image says."""
    n = len(labels)
    zeros = torch.zeros(n)
    press = depth.flatten(1).amax(1) if n else zeros
    return Poses(labels, zeros, zeros, zeros, press)


def _pairs_set(
    pairs: PairSet, sim_background: torch.Tensor, generator: torch.Generator, gel: GelSpec
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


def check_braille_layout(root: Path) -> None:
    """Fail before any work when ``root`` is not a Tactile-Diffusion braille folder."""
    for sub in ("real_fine_tuning/color", "real_fine_tuning/mask", "real/color", "bgs"):
        if not (root / sub).is_dir():
            raise TactileBenchError(
                f"source: {root / sub}: folder not found (expected the Tactile-Diffusion "
                "braille layout: real_fine_tuning/{color,mask}, real/color, bgs)"
            )


def load_layout_sets(
    root: Path,
    gel: GelSpec,
    sim_background: torch.Tensor,
    simulated_classifier: BrailleSet,
    seed: int,
    chars: tuple[str, ...],
) -> dict[str, BrailleSet]:
    """The four sets of a braille_data stage, read from ``root`` (see the module doc)."""
    check_braille_layout(root)
    generator = torch.Generator().manual_seed(seed)
    finetune = _pairs_set(load_braille_pairs(root, "train", gel), sim_background, generator, gel)
    test = _pairs_set(load_braille_pairs(root, "test", gel), sim_background, generator, gel)
    images, labels, background = load_braille_real_images(root, gel)
    finetune.labels = finetune.poses.labels = _relabel(finetune.labels, chars, root)
    test.labels = test.poses.labels = _relabel(test.labels, chars, root)
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
    return {
        "finetune": finetune,
        "test": test,
        "classifier": classifier,
        "classifier_test": classifier_test,
    }
