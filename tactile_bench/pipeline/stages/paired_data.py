"""Stage ``paired_data``: your own sensor's paired folder as the pipeline's data.

``source:`` is a folder in the diagnosis's paired layout (``diagnose.paired``: depth/, real/,
background.png, optional sim/, sim_background.png and gel.json, optional per-label
subfolders), or the Tactile-Diffusion braille release, which ``load_paired`` reads too.
Frames of any size (a DIGIT's 240 x 320) are resized to S x S as ``diagnose --size`` does.
Without sim/ the sim images are the plain simulator's (noise-free, TACTO-like) over the
folder's own no-contact frame, as TACTO composites (``sensor.press_grounding.sim_render``);
the metrics say so (``sim``).

The pairs are split, stratified by label and seeded by the recipe's seed, with
``diagnose.run.stratified_split`` at ``fit_fraction = 1 - holdout``: the split ``calibrate``
and the diagnosis draw with the same seed and share. The stage writes them as braille sets,
so the stages that read a ``braille_data`` stage read this one (``fit_translator``'s
``braille`` slot, ``translate``, ``compare_translators``, ``classify``, ``diagnose``):

- ``finetune`` and ``classifier``: the fit share (one file, ``fit.npz``);
- ``test`` and ``classifier_test``: the held-out share (``heldout.npz``);
- ``all``: every pair in the folder's order (``diagnose`` with ``set: all`` then splits
  them as this stage does).

Labels are the folder's (sorted; "" when unlabelled); the sets hold their positions in the
metrics' ``classes``. The pairs have no poses: x, y and yaw are 0 and ``press_mm`` is each
depth's maximum. Beside the sets: ``fit/`` and ``heldout/`` (the two shares again as paired
folders, at S x S, for ``calibrate`` and the commands: ``share_folder``), ``split.json``
(which pair went where) and ``preview.png``. ``gel_mm`` (the view the S x S frames cover,
from gel.json) is in the metrics: a renderer of these depths needs it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import torch
from pydantic import Field

from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.pixels import to_uint8
from tactile_bench.diagnose.paired import (
    DiagnosisPairs,
    detect_layout,
    label_to_dir,
    load_paired,
    write_paired,
)
from tactile_bench.diagnose.run import MIN_PAIRS, stratified_split
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import Poses
from tactile_bench.guard.args import MAX_SIZE, MIN_SIZE
from tactile_bench.io import atomic_write_json
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    StageResult,
    resolve_source,
)
from tactile_bench.report.figures import sample_grid_png

#: the braille-set outputs and the file each is ({output name: file})
SET_FILES = {
    "all": "all.npz",
    "finetune": "fit.npz",
    "classifier": "fit.npz",
    "test": "heldout.npz",
    "classifier_test": "heldout.npz",
}
FIT_DIR, HELDOUT_DIR, SPLIT_FILE = "fit", "heldout", "split.json"
PREVIEW_ROWS = 6


class PairedDataConfig(StageConfig):
    """Which folder, at which image size, and which share of its pairs is held out."""

    source: str = Field(
        description="a folder in the paired layout (depth/, real/, background.png, optional "
        "sim/, gel.json, per-label subfolders; docs/diagnosis.md), relative to the recipe"
    )
    size: int | None = Field(
        default=None,
        ge=MIN_SIZE,
        le=MAX_SIZE,
        description="frames resized to size x size, as diagnose --size; None: min(64, the "
        "shortest side)",
    )
    holdout: float = Field(
        default=0.5,
        gt=0.0,
        lt=1.0,
        description="share of the pairs held out (test, classifier_test), stratified by "
        "label and seeded by the recipe's seed; the rest is the fit share",
    )


def _root(config: PairedDataConfig, base_dir: Path) -> tuple[str, Path]:
    """The layout and folder ``source:`` names; a missing or foreign folder names the key."""
    try:
        return detect_layout(resolve_source(config.source, base_dir))
    except TactileBenchError as exc:
        raise TactileBenchError(f"source: {exc}") from None


def _check(config: PairedDataConfig, base_dir: Path) -> None:
    layout, root = _root(config, base_dir)
    if layout != "paired" or not (root / "depth").is_dir():
        return  # the loader names what is missing; the release is checked when read
    n = sum(1 for p in (root / "depth").rglob("*") if p.suffix.lower() == ".png")
    _enough(n, root)


def _enough(n: int, root: Path) -> None:
    if n < MIN_PAIRS:
        raise TactileBenchError(
            f"source: {root} holds {n} pair(s); paired_data needs at least {MIN_PAIRS} "
            "(a fit share and a held-out share)"
        )


def to_braille_set(data: DiagnosisPairs, classes: list[str]) -> BrailleSet:
    """``data`` as a braille set: labels are positions in ``classes``; no poses (x, y, yaw
    0, ``press_mm`` the depth's maximum); the real no-contact frame stands for the sim's
    when the folder has none (the sim was composited onto it)."""
    labels = torch.tensor([classes.index(label) for label in data.labels], dtype=torch.int64)
    zeros = torch.zeros(len(data))
    poses = Poses(labels, zeros, zeros, zeros, data.depth.flatten(1).amax(1))
    sim_bg = data.sim_background if data.sim_background is not None else data.background
    return BrailleSet(
        depth=data.depth.float(),
        sim=to_uint8(data.sim),
        real=to_uint8(data.real),
        labels=labels,
        poses=poses,
        sim_background=to_uint8(sim_bg),
        real_background=to_uint8(data.background),
    )


def share_folder(result: StageResult, share: Literal["fit", "heldout"]) -> Path:
    """A paired_data stage's fit or held-out share as a paired folder (``calibrate`` reads
    it); another stage kind is refused in one line."""
    if f"{share}_folder" not in result.outputs:
        raise TactileBenchError(
            f"stage {result.name!r} ({result.kind}) has no {share} folder: connect a "
            "paired_data stage"
        )
    return result.directory / share


def class_names(data: StageResult, n: int) -> list[str]:
    """The names of a data stage's ``n`` first label positions: a paired_data stage's own
    labels, else braille characters."""
    names = data.metrics.get("classes")
    return list(names[:n]) if names else list(CHARACTERS[:n])


def _pair_key(label: str, name: str) -> str:
    """A pair as the folder names it: ``<label folder>/<name>`` (``<name>`` unlabelled)."""
    return f"{label_to_dir(label)}/{name}" if label else name


def _preview(data: DiagnosisPairs, picks: list[int], path: Path, sim_given: bool) -> None:
    sim = "sim" if sim_given else "sim (rendered)"
    sample_grid_png(
        {"depth": data.depth[picks], sim: data.sim[picks], "real": data.real[picks]},
        [_pair_key(data.labels[i], data.names[i]) for i in picks],
        path,
        title=f"paired data: depth | {sim} | real",
    )


def _picks(labels: list[str], k: int) -> list[int]:
    """Up to ``k`` pairs for the preview: the first of each label, then the others in order."""
    first: dict[str, int] = {}
    for i, label in enumerate(labels):
        first.setdefault(label, i)
    chosen = sorted(first.values())
    taken = set(chosen)
    return (chosen + [i for i in range(len(labels)) if i not in taken])[:k]


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: PairedDataConfig = ctx.config
    layout, root = _root(config, ctx.recipe_dir)
    sim_given = layout == "paired" and (root / "sim").is_dir()
    data = load_paired(root, size=config.size, render_missing_sim=True)
    _enough(len(data), root)
    fit_idx, held_idx = stratified_split(data.labels, 1.0 - config.holdout, ctx.seed)
    classes = sorted(set(data.labels))
    every = to_braille_set(data, classes)
    every.save(ctx.directory / SET_FILES["all"])
    every.subset(fit_idx).save(ctx.directory / SET_FILES["finetune"])
    every.subset(held_idx).save(ctx.directory / SET_FILES["test"])
    # re-run after a kill: the shares are written again in place (write_paired is atomic)
    write_paired(ctx.directory / FIT_DIR, data.subset(fit_idx), overwrite=True)
    write_paired(ctx.directory / HELDOUT_DIR, data.subset(held_idx), overwrite=True)
    # their no-contact frames stand in the manifest, so a removed folder reruns the stage
    outputs = SET_FILES | {f"{d}_folder": f"{d}/background.png" for d in (FIT_DIR, HELDOUT_DIR)}
    keys = [_pair_key(label, name) for label, name in zip(data.labels, data.names, strict=True)]
    split = {
        "source": str(root),
        "seed": ctx.seed,
        "holdout": config.holdout,
        "fit_fraction": 1.0 - config.holdout,
        "size": data.size,
        "fit": [keys[i] for i in fit_idx.tolist()],
        "heldout": [keys[i] for i in held_idx.tolist()],
    }
    atomic_write_json(ctx.directory / SPLIT_FILE, split)
    outputs["split"] = SPLIT_FILE
    _preview(data, _picks(data.labels, PREVIEW_ROWS), ctx.directory / "preview.png", sim_given)
    outputs["preview"] = "preview.png"
    both = {"has_sim": True, "has_real": True}
    metrics: dict[str, Any] = {
        "source_root": str(root),
        "layout": layout,
        "n_pairs": len(data),
        "n_fit": len(fit_idx),
        "n_heldout": len(held_idx),
        "size": data.size,
        "gel_mm": list(data.gel_mm),
        "labels": len(classes),
        "classes": classes,
        "holdout": config.holdout,
        # folder: the folder's sim/; rendered: the plain simulator (noise-free) over the
        # folder's no-contact frame (the Tactile-Diffusion release: over the simulator's)
        "sim": "folder" if sim_given else "rendered",
        "sim_background_given": data.sim_background is not None,
        "content": {name: both for name in SET_FILES},
    }
    return outputs, metrics


STAGE = StageKind(
    name="paired_data",
    description="your own sensor's paired folder (depth/, real/, background.png, optional "
    "sim/): a seeded fit / held-out split as braille sets and paired folders",
    config_model=PairedDataConfig,
    run=_run,
    check=_check,
)
