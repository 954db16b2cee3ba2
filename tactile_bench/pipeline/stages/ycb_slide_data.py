"""Stage ``ycb_slide_data``: the pretraining corpus as sharded pairs.

``source: surrogate`` builds the YCB-Slide stand-in; ``source: PATH`` reads real data: the
YCB-Slide release (``real/<object>/dataset_<k>``, depth rendered here, the released
``bgs/bg_<i>.jpg`` as background where present, else each log's first frame), or
Tactile-Diffusion's processed copy (``dataset/<object>/dataset_<k>/{frames,frames_depth}``,
its own split and backgrounds; ``data.ycb_processed``; a log without its split file gets
one drawn from the stage's seed, written under ``splits/`` in the stage folder).

The stand-in's "real" side is ``real_sensor``, or, with the ``sensor`` input connected, the
profile a ``calibrate`` stage fitted to a user's own sensor, over that sensor's gel view: a
corpus to pretrain a translator for a sensor this project has no profile of.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from tactile_bench.data.corpus import load_pairs, read_manifest
from tactile_bench.data.ycb_processed import (
    SPLIT_FILE,
    load_ycb_processed,
    processed_root,
    released_background,
)
from tactile_bench.data.ycb_real import load_ycb_slide_real
from tactile_bench.data.ycb_slide import (
    DEFAULT_PAIRS,
    StandinConfig,
    build_ycb_slide_standin,
    write_corpus,
)
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.objects import OBJECTS
from tactile_bench.io import atomic_write_json
from tactile_bench.pipeline.stages.base import (
    StageConfig,
    StageContext,
    StageKind,
    check_real_sensor,
    real_sensor,
    resolve_source,
)
from tactile_bench.report.figures import sample_grid_png
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.surrogate import SurrogateDigit

log = logging.getLogger("tactile_bench")


class YcbSlideConfig(StageConfig):
    """The corpus: the procedural stand-in (``source: surrogate``) with its size, objects and
    surrogate unit, or real recordings in the original YCB-Slide layout (``source: PATH``)."""

    source: str = Field(
        default="surrogate",
        description="surrogate: build the procedural stand-in; or a YCB-Slide release folder "
        "(or Tactile-Diffusion's processed copy of it)",
    )
    stride: int = Field(default=1, ge=1, description="subsample a real 30 Hz log")
    n_pairs: int = Field(
        default=DEFAULT_PAIRS, ge=10, description="stand-in (depth, real) pairs (the paper: 180000)"
    )
    objects: list[str] = Field(
        default=list(OBJECTS), description="YCB objects to slide over (see `list`)"
    )
    real_sensor: str = Field(
        default="digit", description="surrogate profile playing 'real': a name or a YAML path"
    )
    image_size: int = Field(default=64, ge=16, le=256, description="image side in pixels")
    skip_bad: bool = Field(default=False, description="drop unreadable frames, listed in skipped")


def _check(config: YcbSlideConfig, base_dir: Path) -> None:
    if config.source != "surrogate":
        root = resolve_source(config.source, base_dir)
        if not (root / "real").is_dir() and processed_root(root) is None:
            raise TactileBenchError(
                f"source: {root} is not a YCB-Slide folder (expected {root / 'real'}/<object>/, "
                "or Tactile-Diffusion's copy: dataset/<object>/dataset_<k>/frames_depth)"
            )
        return
    unknown = [o for o in config.objects if o not in OBJECTS]
    if unknown:
        raise TactileBenchError(f"objects: unknown {unknown}; known: {', '.join(OBJECTS)}")
    check_real_sensor(config.real_sensor, base_dir)


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: YcbSlideConfig = ctx.config
    skipped: list[tuple[str, str]] | None = [] if config.skip_bad else None
    source_info: dict[str, Any] = {}
    root = resolve_source(config.source, ctx.recipe_dir) if config.source != "surrogate" else None
    if root is not None and processed_root(root) is not None:
        objects = None if config.objects == list(OBJECTS) else config.objects
        pairs, source_info = load_ycb_processed(
            root,
            objects=objects,
            gel=GelSpec(size=config.image_size),
            stride=config.stride,
            skipped=skipped,
            seed=ctx.seed,
            write_splits_to=ctx.directory / "splits",
        )
        source_info["layout"] = "tactile-diffusion processed copy"
        manifest = write_corpus(pairs, ctx.directory, test_mask=pairs.meta["test"] == 1)
    elif root is not None:
        pairs = load_ycb_slide_real(
            root,
            gel=GelSpec(size=config.image_size),
            stride=config.stride,
            progress=ctx.progress,
            skipped=skipped,
        )
        names = sorted({p.name for p in (root / "real").iterdir() if p.is_dir()})
        source_info = {
            "layout": "ycb-slide release",
            "backgrounds": {
                n: str(released_background(root / "bgs", n) or "first frame of each log")
                for n in names
            },
        }
        manifest = write_corpus(pairs, ctx.directory)
    else:
        surrogate, gel = _standin_sensor(ctx)
        manifest = build_ycb_slide_standin(
            ctx.directory,
            config=StandinConfig(
                n_pairs=config.n_pairs, seed=ctx.seed, objects=tuple(config.objects)
            ),
            gel=gel,
            real_sensor=surrogate,
            progress=ctx.progress,
        )
    _preview(ctx.directory)
    outputs = {
        "manifest": "manifest.json",
        "backgrounds": "backgrounds.npz",
        "preview": "preview.png",
    }
    for shard in sorted((ctx.directory / "shards").glob("*.npz")):
        outputs[f"shard_{shard.stem}"] = f"shards/{shard.name}"
    for split in sorted((ctx.directory / "splits").glob(f"*/*/{SPLIT_FILE}")):
        outputs[f"split_{split.parent.parent.name}_{split.parent.name}"] = str(
            split.relative_to(ctx.directory)
        )
    counts = {k: manifest[k] for k in ("n_train", "n_test", "frames_dropped") if k in manifest}
    counts |= {"source": source_info} if source_info else {}
    if skipped is not None:  # skip_bad: say what was left out, in the log and in a file
        for _, why in skipped:
            log.warning("skipped %s", why)
        atomic_write_json(ctx.directory / "skipped.json", [list(s) for s in skipped])
        outputs["skipped"] = "skipped.json"
        counts["skipped"] = len(skipped)
    return outputs, counts


def _standin_sensor(ctx: StageContext) -> tuple[SurrogateDigit, GelSpec]:
    """The stand-in's "real" sensor and gel view: a calibrate stage's profile over its own
    view when ``sensor`` is connected, else ``real_sensor`` over the DIGIT's view."""
    config: YcbSlideConfig = ctx.config
    calibrated = ctx.optional_input("sensor")
    if calibrated is None:
        return real_sensor(config.real_sensor, ctx.recipe_dir), GelSpec(size=config.image_size)
    if "profile" not in calibrated.outputs:
        raise TactileBenchError(
            f"stage {ctx.name}: sensor: {calibrated.name!r} ({calibrated.kind}) wrote no "
            "profile; connect a calibrate stage"
        )
    surrogate = SurrogateDigit.from_profile(calibrated.path("profile"))
    return surrogate, surrogate.gel(config.image_size)


def _preview(root: Path, per_object: int = 1) -> None:
    """depth | sim | real for the middle frame of one test recording of each object."""
    pairs = load_pairs(root, "all")
    objects = pairs.meta["object"]
    picks = []
    for obj in np.unique(objects):
        idx = np.flatnonzero(objects == obj)
        picks += idx[len(idx) // 2 :: max(1, len(idx))][:per_object].tolist()
    names = read_manifest(root).get("meta_object_names")
    labels = [names[int(objects[i])] if names else f"object {int(objects[i])}" for i in picks]
    columns = {"depth": pairs.depth[picks], "real": pairs.real[picks]}
    if pairs.sim is not None:
        columns = {"depth": pairs.depth[picks], "sim": pairs.sim[picks], "real": pairs.real[picks]}
    sample_grid_png(columns, labels, root / "preview.png", title="corpus frames")


STAGE = StageKind(
    name="ycb_slide_data",
    description="build the YCB-Slide stand-in pretraining corpus (split by trajectory)",
    config_model=YcbSlideConfig,
    run=_run,
    input_slots={"sensor": False},
    check=_check,
)
