"""``tactile_bench check PATH``: read a dataset, recipe, profile or checkpoint, and say if it is
usable, before a long run finds out at 3 a.m.

The layout is recognised from the path (``--layout`` forces one). Every file is read the way
the pipeline reads it, so the first problem is the same one-line error (naming the file) that
the run would hit. ``--skip-bad`` instead skips bad samples of a dataset folder and lists them.

A command of the application layer (it reads what every layer reads: data, paired sets,
recipes, checkpoints), not of ``data/``. Each reader imports its layer inside the function
on purpose: the CLI imports this module to build its parser, and ``--help`` must not load
torch.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tactile_bench.errors import TactileBenchError

Skipped = list[tuple[str, str]]


def _tactile_diffusion(path: Path, skipped: Skipped | None, seed: int = 0) -> str:
    """Read what a ``braille_data`` stage with this ``source:`` reads, split included: the
    release's file, or the split the stage would draw with ``seed`` (not written anywhere)."""
    from tactile_bench.data.tactile_diffusion import (
        SIM_BACKGROUND_ID,
        braille_root,
        load_braille_pairs,
        load_braille_real_images,
        split_for_run,
    )

    base = braille_root(path)
    pairs = load_braille_pairs(base, "all", skipped=skipped)
    text = f"Tactile-Diffusion braille layout at {base}: {len(pairs)} fine-tuning pairs"
    split, origin = split_for_run(base, seed)
    n = {
        part: len(load_braille_pairs(base, {k: v[part] for k, v in split.items()}, skipped=skipped))
        for part in ("train", "test")
    }
    text += f"; translator split {n['train']} train / {n['test']} test ({origin})"
    images, _, _ = load_braille_real_images(base, skipped=skipped)
    text += f"; {len(images)} real test frames"
    if (base / "sim_tacto" / "color").is_dir():
        sims, _, _ = load_braille_real_images(
            base, subset="sim_tacto", background_id=SIM_BACKGROUND_ID, skipped=skipped
        )
        text += f"; {len(sims)} release sim frames (sim_source: release)"
    if skipped:  # the split's parts re-read files "all" read: list each bad file once
        skipped[:] = list(dict.fromkeys(skipped))
    return text


def _ycb_slide(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.data.ycb_processed import released_background
    from tactile_bench.data.ycb_real import load_ycb_slide_real

    pairs = load_ycb_slide_real(path, skipped=skipped)
    logs = len(set(pairs.meta["trajectory"].tolist()))
    objects = sorted(p.name for p in (path / "real").iterdir() if p.is_dir())
    bgs = "; ".join(
        f"{o}: {released_background(path / 'bgs', o) or 'first frame of each log'}" for o in objects
    )
    return (
        f"YCB-Slide real layout: {len(pairs)} (depth, frame) pairs from {logs} logs; "
        f"backgrounds {bgs}"
    )


def _ycb_processed(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.data.ycb_processed import load_ycb_processed

    pairs, info = load_ycb_processed(path, skipped=skipped)
    n_test = int(pairs.meta["test"].sum())
    logs = len(set(pairs.meta["trajectory"].tolist()))
    backgrounds = info["backgrounds"]
    assert isinstance(backgrounds, dict)
    bg = "; ".join(f"{k}: {v}" for k, v in backgrounds.items())
    return (
        f"Tactile-Diffusion YCB-Slide copy at {info['root']}: {len(pairs)} (depth, frame) "
        f"pairs from {logs} logs ({len(pairs) - n_test} train / {n_test} test, split: "
        f"{info['splits']}; {info['listed_without_depth']} listed frames without a "
        f"heightmap left out); backgrounds {bg}"
    )


def _corpus(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.data.corpus import load_pairs

    pairs = load_pairs(path, "all", verify=True)
    return f"pair-set corpus: {len(pairs)} pairs, every shard matches its manifest hash"


def _paired(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.diagnose.paired import load_paired

    data = load_paired(path)
    return f"paired layout: {len(data.names)} (depth, sim, real) triples"


def _recipe(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.pipeline.recipe import load_recipe

    recipe = load_recipe(path)
    return f"recipe {recipe.name!r}: {len(recipe.stages)} stages, all configs valid"


def _profile(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.sensor.surrogate import SurrogateDigit

    sensor = SurrogateDigit.from_profile(path)
    return f"surrogate profile {sensor.name!r}: effects {', '.join(sensor.effects_enabled)}"


def _checkpoint(path: Path, skipped: Skipped | None) -> str:
    from tactile_bench.translators.registry import load_checkpoint

    translator = load_checkpoint(path)
    n = sum(p.numel() for p in translator.parameters())
    return f"checkpoint of translator {translator.name!r}, {n} parameters"


LAYOUTS: dict[str, Callable[[Path, Skipped | None], str]] = {
    "tactile-diffusion": _tactile_diffusion,
    "ycb-slide": _ycb_slide,
    "ycb-processed": _ycb_processed,
    "corpus": _corpus,
    "paired": _paired,
    "recipe": _recipe,
    "profile": _profile,
    "checkpoint": _checkpoint,
}


def detect(path: Path) -> str:
    """Which of ``LAYOUTS`` a path is, from its name and its first level of content."""
    if not path.exists():
        raise TactileBenchError(f"{path}: not found")
    if path.is_file():
        if path.suffix in (".pt", ".pth", ".ckpt"):
            return "checkpoint"
        if path.suffix in (".yaml", ".yml"):
            try:
                head = path.read_text(errors="replace")
            except OSError as exc:
                raise TactileBenchError(f"{path}: cannot read ({exc})") from None
            return "recipe" if "stages" in head else "profile"
        raise TactileBenchError(f"{path}: unknown kind of file (expected .yaml, .pt or a folder)")
    if (path / "manifest.json").exists():
        return "corpus"
    if (
        (path / "obj_models").is_dir()
        or (path / "real").is_dir()
        and any((path / "real").glob("*/dataset_*"))
    ):
        return "ycb-slide"
    from tactile_bench.data.ycb_processed import processed_root

    if processed_root(path) is not None and not (path / "braille").is_dir():
        return "ycb-processed"
    if any((path / sub / "real_fine_tuning").is_dir() for sub in (".", "braille")):
        return "tactile-diffusion"  # the same rule as tactile_diffusion.braille_root
    if (path / "depth").is_dir():
        return "paired"
    raise TactileBenchError(
        f"{path}: not a layout tactile_bench reads (Tactile-Diffusion braille or YCB-Slide "
        "copy, YCB-Slide real, "
        "a pair-set corpus with manifest.json, or the paired depth/ sim/ real/ layout)"
    )


def _cmd_check(ns: argparse.Namespace) -> int:
    path = Path(ns.path)
    layout = ns.layout or detect(path)
    skipped: Skipped | None = [] if ns.skip_bad else None
    if layout == "tactile-diffusion":
        summary = _tactile_diffusion(path, skipped, ns.seed)
    else:
        summary = LAYOUTS[layout](path, skipped)
    print(f"ok: {path}: {summary}")
    if skipped:
        print(f"skipped {len(skipped)} bad sample(s) (--skip-bad):")
        for _, why in skipped:
            print(f"  {why}")
    return 0


def register(subparsers: Any) -> None:
    """Add ``check`` to the command line."""
    parser = subparsers.add_parser(
        "check",
        help="read a dataset folder, recipe, profile or checkpoint and report the first problem",
    )
    parser.add_argument("path", help="folder or file to check")
    parser.add_argument("--layout", choices=sorted(LAYOUTS), help="default: recognised")
    parser.add_argument(
        "--skip-bad",
        action="store_true",
        help="skip bad samples of a dataset folder and list them, instead of stopping",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="braille data without a split file: draw the split a recipe of this seed draws",
    )
    parser.set_defaults(func=_cmd_check)
