"""Command line: ``python -m tactile_bench {fit,list,...}``.

``main(args)`` runs in-process (tests call it directly) and returns the exit
code. Problems with the user's input are TactileBenchError: one line on
stderr, exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path

from tactile_bench.errors import TactileBenchError

EXIT_USER_ERROR = 2


def _cmd_fit(ns: argparse.Namespace) -> int:
    from tactile_bench.pipeline.recipe import load_recipe
    from tactile_bench.pipeline.runner import run_recipe

    recipe = load_recipe(ns.recipe, ns.set)
    if ns.run_dir:
        recipe.run_dir = Path(ns.run_dir)
    results = run_recipe(recipe, force=tuple(ns.force), progress=not ns.no_progress)
    print(f"\nrun directory: {recipe.run_dir}")
    for result in results:
        state = "cached" if result.cached else "ran"
        print(
            f"  {result.name:<24} {state:<7} {result.wall_time_s:8.1f} s  {result.directory.name}"
        )
    table = recipe.run_dir / "results.md"
    if table.exists():
        print()
        print(table.read_text())
    return 0


def _list_translators() -> None:
    from tactile_bench.translators.registry import discover

    print("translators (entry-point group tactile_bench.translators):")
    for name, entry in discover().items():
        try:
            entry.load()
            status = ""
        except TactileBenchError as exc:
            status = f"  [broken: {exc}]"
        print(f"  {name:<16} {entry.target}  ({entry.distribution}){status}")


def _list_effects() -> None:
    from tactile_bench.effects import EFFECTS

    print("effects (the surrogate DIGIT's physics; order: pose -> geometry -> optics -> camera):")
    for name, effect in EFFECTS.items():
        first_sentence = " ".join(effect.description.split()).split(". ")[0].rstrip(".")
        print(f"  {name:<20} [{effect.stage}] {first_sentence}.")
        for q in effect.params:
            print(
                f"      {q.name:<18} {q.default:g} {q.unit:<8} range [{q.low:g}, {q.high:g}], "
                f"neutral {q.neutral:g}; source: {q.source}"
            )


def _list_recipes() -> None:
    print("recipes (./recipes):")
    for path in sorted(Path("recipes").glob("*.yaml")):
        print(f"  {path}")


def _list_stages() -> None:
    from tactile_bench.pipeline.stages import STAGES

    print("stage kinds:")
    for name, kind in STAGES.items():
        print(f"  {name:<14} {kind.description}")


LISTINGS: dict[str, Callable[[], None]] = {
    "translators": _list_translators,
    "effects": _list_effects,
    "recipes": _list_recipes,
    "stages": _list_stages,
}


def _cmd_list(ns: argparse.Namespace) -> int:
    for what in [ns.what] if ns.what else list(LISTINGS):
        LISTINGS[what]()
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser, with a subcommand per job."""
    parser = argparse.ArgumentParser(
        prog="tactile_bench",
        description="Bridge the tactile sim-to-real gap: simulate, translate, classify, report.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    fit = sub.add_parser("fit", help="run a recipe (cached stages; reruns skip finished work)")
    fit.add_argument("recipe", help="path to a recipe YAML, e.g. recipes/smoke.yaml")
    fit.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a recipe value: seed=1, trainer.max_epochs=2, STAGE.key=value",
    )
    fit.add_argument(
        "--force",
        action="append",
        default=[],
        metavar="STAGE",
        help="redo this stage even if it finished before (repeatable)",
    )
    fit.add_argument("--run-dir", help="where to write (default: runs/<recipe name>)")
    fit.add_argument("--no-progress", action="store_true", help="no progress bars")
    fit.set_defaults(func=_cmd_fit)

    lst = sub.add_parser("list", help="list translators, effects, recipes and stage kinds")
    lst.add_argument("what", nargs="?", choices=sorted(LISTINGS), help="only this listing")
    lst.set_defaults(func=_cmd_list)
    return parser


def main(args: list[str] | None = None) -> int:
    """Run the command line; returns the exit code instead of exiting, for in-process tests."""
    os.environ.setdefault("WANDB_MODE", "offline")
    parser = build_parser()
    try:
        ns = parser.parse_args(args)
    except SystemExit as exc:  # --help or a usage error: argparse already printed
        return int(exc.code or 0)
    logging.basicConfig(
        level=logging.DEBUG if ns.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return ns.func(ns)
    except TactileBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("interrupted: finished stages are kept; rerun to resume", file=sys.stderr)
        return 130
