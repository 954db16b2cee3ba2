"""Command line: ``python -m tactile_bench {fit,list,...}``.

``main(args)`` runs in-process (tests call it directly) and returns the exit
code. Problems with the user's input are TactileBenchError: one line on
stderr, exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from tactile_bench.allocator import keep_freed_memory
from tactile_bench.cli_args import (
    check_arguments,
    check_environment,
    command_name,
    output_locks,
    output_of,
)
from tactile_bench.console import configure_logging
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.limits import disk_full_error

EXIT_USER_ERROR = 2

# Modules that add a subcommand: each defines ``register(subparsers) -> None`` and sets
# ``func`` on its parser. Listed, not discovered, so a command appears only when it ships.
# They are imported to build every parser, so they import no torch or Lightning at module
# level: ``--help`` answers in a fraction of a second (tests/test_cli_startup.py).
COMMAND_MODULES: tuple[str, ...] = (
    "tactile_bench.diagnose.commands",
    "tactile_bench.calibrate.commands",
    "tactile_bench.read.commands",
    "tactile_bench.check",
    "tactile_bench.bench.commands",
)


def _cmd_fit(ns: argparse.Namespace) -> int:
    from tactile_bench.pipeline.launch import is_leader
    from tactile_bench.pipeline.recipe import load_recipe
    from tactile_bench.pipeline.runner import run_recipe

    recipe = load_recipe(ns.recipe, ns.set)
    if ns.run_dir:
        recipe.run_dir = Path(ns.run_dir)
    if ns.jobs is not None:
        recipe.jobs = ns.jobs
    results = run_recipe(recipe, force=tuple(ns.force), progress=not ns.no_progress)
    if not is_leader():  # another rank of a launch: rank 0 prints the run
        return 0
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

    print(
        "effects (the surrogate DIGIT's physics; [what each acts on], in order: "
        "pose -> geometry -> optics -> camera):"
    )
    for name, effect in EFFECTS.items():
        first_sentence = " ".join(effect.description.split()).split(". ")[0].rstrip(".")
        print(f"  {name:<20} [{effect.acts_on}] {first_sentence}.")
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
    from tactile_bench.pipeline.stages.base import config_keys

    print("stage kinds (below each: its `config:` keys, default  # meaning):")
    for name, kind in STAGES.items():
        print(f"  {name:<14} {kind.description}")
        for key in config_keys(kind.config_model):
            print(f"      {key.key}: {key.default}  # {key.description}")


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


def _cmd_render(ns: argparse.Namespace) -> int:
    from tactile_bench.geometry.braille import CHARACTERS
    from tactile_bench.geometry.objects import OBJECTS
    from tactile_bench.report.contact_sheet import render_contact_sheet

    bad = [c for c in ns.chars if c not in CHARACTERS]
    if bad:
        raise TactileBenchError(f"--chars: not braille characters of the paper: {bad}")
    unknown = [o for o in ns.objects if o not in OBJECTS]
    if unknown:
        raise TactileBenchError(f"--objects: unknown {unknown}; known: {', '.join(OBJECTS)}")
    path = render_contact_sheet(ns.chars, ns.objects, ns.profile, ns.out, ns.seed)
    print(f"wrote {path}")
    return 0


def _cmd_data(ns: argparse.Namespace) -> int:
    import time

    from tactile_bench.data.ycb_slide import StandinConfig, build_ycb_slide_standin
    from tactile_bench.geometry.objects import OBJECTS
    from tactile_bench.sensor.surrogate import SurrogateDigit

    objects = tuple(ns.objects or OBJECTS)
    pairs = ns.pairs if ns.pairs is not None else StandinConfig().n_pairs
    config = StandinConfig(n_pairs=pairs, seed=ns.seed, objects=objects)
    start = time.perf_counter()
    manifest = build_ycb_slide_standin(
        ns.out,
        config=config,
        real_sensor=SurrogateDigit.from_profile(ns.profile),
        progress=not ns.no_progress,
    )
    wall = time.perf_counter() - start
    n = manifest["n_train"] + manifest["n_test"]
    print(
        f"wrote {ns.out}: {manifest['n_train']} train + {manifest['n_test']} test pairs "
        f"(split by trajectory), {manifest.get('frames_dropped', 0)} frames dropped; "
        f"{wall:.1f} s, {n / wall:.1f} pairs/s"
    )
    return 0


def _json_out(ns: argparse.Namespace, report: dict) -> None:
    """``--json``: every number printed (``-``, the flag alone) or written to ``--json FILE``."""
    import json

    from tactile_bench.io import atomic_write_text

    text = json.dumps(report, indent=2, default=float)
    if ns.json == "-":
        print(text)
    else:
        atomic_write_text(Path(ns.json), text + "\n")


def _cmd_ground(ns: argparse.Namespace) -> int:
    from contextlib import nullcontext

    from tactile_bench.guard.outputs import OutputLock, check_output_file

    json_file = ns.json is not None and ns.json != "-"
    if json_file:
        check_output_file(ns.json, "--json", (".json",))
    with OutputLock(ns.json, "--json") if json_file else nullcontext():
        if ns.pairs_dir is not None:
            return _ground_on_pairs(ns)
        if ns.refit or ns.profile:
            return _ground_on_presses(ns)
        return _ground_digit(ns)


def _ground_digit(ns: argparse.Namespace) -> int:
    """``ground``: the DIGIT's background and optics against the real reference files."""
    from tactile_bench.sensor.grounding import (
        BACKGROUND_FILE,
        POLYCALIB_FILE,
        default_real_dir,
        grounding_report,
    )

    real_dir = Path(ns.real_dir) if ns.real_dir else default_real_dir()
    if real_dir is None or not real_dir.is_dir():
        raise TactileBenchError(
            f"{ns.real_dir or '../shared/real'}: no folder of real DIGIT measurements "
            "(digit_background_240x320.jpg, digit_polycalib.npz); pass --real-dir"
        )
    if not any((real_dir / name).is_file() for name in (BACKGROUND_FILE, POLYCALIB_FILE)):
        # a table of "absent" on every line is no measurement: say what is missing
        raise TactileBenchError(
            f"{real_dir}: nothing to measure: neither {BACKGROUND_FILE} nor {POLYCALIB_FILE}"
        )
    report = grounding_report(real_dir)
    if ns.json is not None:
        _json_out(ns, report)
        return 0
    print(f"surrogate DIGIT against real measurements in {real_dir}")

    def rgb(values: list[float]) -> str:
        return " / ".join(f"{v:.1f}" for v in values)

    for key, label in (("background", "digit"), ("background_digit_b", "digit-b")):
        b = report[key]
        if b is None:
            print(f"  background ({label}): reference frame absent")
            continue
        print(
            f"  background ({label}): mean RGB {rgb(b['surrogate_mean'])} vs real "
            f"{rgb(b['real_mean'])}; std {rgb(b['surrogate_std'])} vs {rgb(b['real_std'])}; "
            f"RMSE {b['rmse']:.2f}, low-frequency RMSE {b['lowfreq_rmse']:.2f} (0-255)"
        )
    fit, ours = report["optical_response"], report["surrogate_response"]
    if fit is None:
        print("  optical response: calibration absent")
    else:
        print(
            f"  optical response (fitted model vs calibration): MAE {fit['mae']:.2f} "
            f"(below 60 deg {fit['mae_below_60deg']:.2f}; per channel "
            f"{rgb(fit['mae_per_channel'])}) of a mean |response| {fit['table_mean_abs']:.1f}, "
            f"relative {fit['relative_error']:.3f}, {fit['n_numbers_embedded']} numbers"
        )
        print(
            f"  optical response (surrogate's own torch code vs calibration): MAE "
            f"{ours['mae']:.2f} (below 60 deg {ours['mae_below_60deg']:.2f})"
        )
    return 0


def _ground_on_presses(ns: argparse.Namespace) -> int:
    """``ground --profile``: a profile against held-out real presses (or ``--refit``)."""
    from tactile_bench.real_presses import ground_profile, print_ground, refit_module

    if ns.refit:
        print(refit_module(), end="")
        return 0
    figure = Path(ns.figure) if ns.figure else None
    if figure is not None and (figure.suffix.lower() != ".png" or figure.is_dir()):
        raise TactileBenchError(f"--figure {figure}: must be a .png file path")
    if figure is not None and figure.parent.exists() and not figure.parent.is_dir():
        raise TactileBenchError(f"--figure {figure}: {figure.parent} is not a folder")
    report = ground_profile(ns.profile, size=ns.size, figure=figure)
    if ns.json is not None:
        _json_out(ns, report)
    else:
        print_ground(report)
        if figure is not None:
            print(f"  figure: {figure}")
    return 0


def _ground_on_pairs(ns: argparse.Namespace) -> int:
    """``ground --profile P --pairs DIR``: a profile on every pair of a paired folder."""
    from tactile_bench.real_presses import ground_pairs, print_ground_pairs

    if ns.profile is None:
        raise TactileBenchError("--pairs: needs --profile (the profile to score on the pairs)")
    for flag_, value in (
        ("--refit", ns.refit),
        ("--figure", ns.figure),
        ("--real-dir", ns.real_dir),
    ):
        if value:
            raise TactileBenchError(f"{flag_}: not with --pairs")
    report = ground_pairs(ns.profile, Path(ns.pairs_dir), size=ns.size)
    if ns.json is not None:
        _json_out(ns, {k: report[k] for k in ("n_pairs", "sim", "profile")})
    if ns.json != "-":
        print_ground_pairs(report)
        if ns.json is not None:
            print(f"  wrote {ns.json}")
    return 0


def _cmd_real_translators(ns: argparse.Namespace) -> int:
    """``real-translators``: cGAN and diffusion fitted on half the real presses, tested on
    the other half beside plain and calibrated sim."""
    import json

    from tactile_bench.io import atomic_write_json
    from tactile_bench.real_presses import profile_sensor, translators_on_presses

    profile_sensor(ns.sensor)  # a sensor without real presses fails before any work
    for name in ("pretrain_steps", "finetune_steps", "cgan_steps", "pretrain_pairs"):
        if getattr(ns, name) < 1:
            raise TactileBenchError(f"--{name.replace('_', '-')}: must be at least 1")
    out = Path(ns.out)
    if out.exists() and not out.is_dir():
        raise TactileBenchError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    report = translators_on_presses(
        ns.sensor,
        out,
        pretrain_pairs=ns.pretrain_pairs,
        pretrain_steps=ns.pretrain_steps,
        finetune_steps=ns.finetune_steps,
        cgan_steps=ns.cgan_steps,
    )
    atomic_write_json(out / "report.json", report)
    print(
        f"{ns.sensor}: fitted on {report['n_fit']} real presses, measured on "
        f"{report['n_heldout']} held-out ones"
    )
    print(f"  {'row':<15} {'SSIM':>7} {'MSE':>8} {'KID':>16}")
    for name, r in report["rows"].items():
        kid = f"{r['kid']:>8.4f} +- {r['kid_std']:.4f}"
        print(f"  {name:<15} {r['ssim']:>7.4f} {r['mse']:>8.1f} {kid}")
    print(f"  seconds: {json.dumps(report['seconds'])}, total {report['total_seconds']}")
    print(f"wrote {out / 'report.json'} and {report['figure']}")
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one ``error:`` line (the usage stays in ``--help``)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USER_ERROR, f"error: {self.prog}: {message} (see {self.prog} --help)\n")


def command_paths(parser: argparse.ArgumentParser) -> list[list[str]]:
    """Every command and nested subcommand of ``parser``, as argument lists
    (``[]``, ``["list"]``, ``["data", "ycb-slide"]``): what ``--help`` can be asked of."""
    found: list[list[str]] = [[]]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += [[name, *rest] for rest in command_paths(sub)]
    return found


def build_parser() -> argparse.ArgumentParser:
    """The argument parser, with a subcommand per job (subparsers share its class)."""
    parser = _Parser(
        prog="tactile_bench",
        description="Bridge the tactile sim-to-real gap: simulate, translate, classify, report.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch CPU threads (default: torch's choice; 1 is faster when the cores are busy)",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _add_fit(sub)
    _add_render(sub)
    _add_data(sub)
    _add_ground(sub)
    _add_real_translators(sub)
    _add_list(sub)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(sub)
    return parser


def _add_fit(sub: argparse._SubParsersAction) -> None:
    """``fit RECIPE``: the main job, a recipe's stages run or taken from the cache."""
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
    fit.add_argument(
        "--jobs",
        type=int,
        metavar="N",
        help="run up to N stages that do not read each other side by side, each in its own "
        "process on cores/N threads (default: the recipe's jobs, else 1)",
    )
    fit.set_defaults(func=_cmd_fit)


def _add_render(sub: argparse._SubParsersAction) -> None:
    """``render``: a contact sheet of what each surrogate effect does."""
    render = sub.add_parser(
        "render", help="contact sheet: depth | sim | each surrogate effect alone | all effects"
    )
    render.add_argument("--chars", nargs="*", default=["A", "B", "#"], help="braille characters")
    render.add_argument(
        "--objects",
        nargs="*",
        default=["004_sugar_box"],
        help="pretraining objects (see `list`), one sliding frame each",
    )
    render.add_argument("--profile", default="digit", help="surrogate profile name or YAML path")
    render.add_argument("--out", default="contact_sheet.png", help="PNG to write")
    render.add_argument("--seed", type=int, default=0)
    render.set_defaults(func=_cmd_render)


def _add_data(sub: argparse._SubParsersAction) -> None:
    """``data ycb-slide``: the pretraining corpus built outside a recipe."""
    data = sub.add_parser("data", help="build a dataset on its own (outside a recipe)")
    data_sub = data.add_subparsers(dest="dataset", required=True)
    ycb = data_sub.add_parser("ycb-slide", help="the YCB-Slide stand-in pretraining corpus")
    ycb.add_argument("--pairs", type=int, default=None, help="number of (depth, real) pairs")
    ycb.add_argument("--out", default="data/ycb_slide_standin", help="output directory")
    ycb.add_argument("--objects", nargs="*", help="subset of objects (default: all ten)")
    ycb.add_argument("--profile", default="digit", help="surrogate profile playing 'real'")
    ycb.add_argument("--seed", type=int, default=0)
    ycb.add_argument("--no-progress", action="store_true")
    ycb.set_defaults(func=_cmd_data)


def _add_ground(sub: argparse._SubParsersAction) -> None:
    """``ground``: the surrogate held against real measurements."""
    ground = sub.add_parser(
        "ground",
        help="compare the surrogate with real measurements: a DIGIT's background and optics, "
        "or (--profile) held-out real GelSight presses",
    )
    ground.add_argument("--real-dir", help="folder with the reference files (default: found)")
    ground.add_argument(
        "--json",
        nargs="?",
        const="-",
        metavar="FILE",
        help="every number as JSON: printed, or written to FILE (.json)",
    )
    ground.add_argument(
        "--profile",
        help="a GelSight profile (gelsight, gelsight-mini) against held-out real presses "
        "from the taxim package (pip install -e '.[real]'); with --pairs any profile "
        "(a name or a YAML path)",
    )
    ground.add_argument(
        "--pairs",
        dest="pairs_dir",
        metavar="DIR",
        help="with --profile: score it and the plain simulator on every pair of a paired "
        "folder (depth/, real/, background.png, gel.json)",
    )
    ground.add_argument("--size", type=int, default=64, help="image side the pairs are scored at")
    ground.add_argument("--figure", help="with --profile: write depth | sim | surrogate | real")
    ground.add_argument(
        "--refit",
        action="store_true",
        help="refit the GelSight profiles' numbers from the even presses; print the module",
    )
    ground.set_defaults(func=_cmd_ground)


def _add_real_translators(sub: argparse._SubParsersAction) -> None:
    """``real-translators SENSOR``: both translators on real GelSight presses."""
    rt = sub.add_parser(
        "real-translators",
        help="cGAN and diffusion on real GelSight presses (taxim package): fit half, test half",
    )
    rt.add_argument("sensor", choices=("gelsight", "gelsight-mini"))
    rt.add_argument("--out", required=True, metavar="DIR", help="folder for models and report")
    rt.add_argument("--pretrain-pairs", type=int, default=600, help="stand-in corpus size")
    rt.add_argument("--pretrain-steps", type=int, default=100, help="diffusion pretraining")
    rt.add_argument("--finetune-steps", type=int, default=60, help="diffusion on real presses")
    rt.add_argument("--cgan-steps", type=int, default=200, help="cGAN on real presses")
    rt.set_defaults(func=_cmd_real_translators)


def _add_list(sub: argparse._SubParsersAction) -> None:
    """``list``: what a recipe can name (translators, effects, recipes, stages)."""
    lst = sub.add_parser("list", help="list translators, effects, recipes and stage kinds")
    lst.add_argument("what", nargs="?", choices=sorted(LISTINGS), help="only this listing")
    lst.set_defaults(func=_cmd_list)


def _os_error(exc: OSError, ns: argparse.Namespace) -> str:
    """The file and the system's reason; for a full disk, the command, the file (or the
    command's output) and the space left there."""
    full = disk_full_error(exc, output_of(ns) or Path.cwd())
    if full is not None:
        return f"{command_name(ns)}: {full}"
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


def main(args: list[str] | None = None) -> int:
    """Run the command line; returns the exit code instead of exiting, for in-process tests."""
    os.environ.setdefault("WANDB_MODE", "offline")
    # Freed tensor memory stays in the process for the next tensor instead of being faulted
    # in afresh (tactile_bench.allocator; what it gains: docs/results/code_figures.md).
    keep_freed_memory()
    if sys.stdout is None:  # started with stdout closed (``cmd >&-``): print goes nowhere
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - lives as long as the process
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 prints escaped
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            reconfigure(errors="backslashreplace")
    parser = build_parser()
    try:
        ns = parser.parse_args(args)
    except SystemExit as exc:  # --help or a usage error: argparse already printed
        return int(exc.code or 0)
    # Idle OpenMP threads sleep instead of spinning: on a busy laptop core, spinning made
    # 2 threads slower than 1 (bench: docs/results/bench.md). Read when torch first loads,
    # which the parser does not do. A command of many small ops sets None: the runtime's
    # spin-then-sleep (diagnose.commands.KEEP_OMP_WAIT_POLICY).
    policy = getattr(ns, "omp_wait_policy", "PASSIVE")
    if policy:
        os.environ.setdefault("OMP_WAIT_POLICY", policy)
    configure_logging(logging.DEBUG if ns.verbose else logging.INFO)
    try:
        # every argument, output location and environment setting, before any work
        check_arguments(ns)
        check_environment()
        if ns.threads is not None:
            import torch

            torch.set_num_threads(ns.threads)
        with output_locks(ns):
            code = ns.func(ns)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except BrokenPipeError:
        # the reader left early (``list effects | head``): not an error of ours. Point
        # stdout at /dev/null so the interpreter's final flush does not raise again
        # (the Python docs' recipe, "Note on SIGPIPE" in the signal module)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except TactileBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except ModuleNotFoundError as exc:
        # a dependency missing from this Python (a clone run without installing it): the
        # install line, not a traceback. One of our own modules missing is a bug: raised
        if not exc.name or exc.name.split(".")[0] == "tactile_bench":
            raise
        print(
            f"error: the package {exc.name!r} is not installed in this Python "
            f"({sys.executable}); install tactile_bench first: "
            "pip install torch==2.13.0 && pip install -e .",
            file=sys.stderr,
        )
        return EXIT_USER_ERROR
    except OSError as exc:  # the machine's answer about a file: a full disk, a name too long
        print(f"error: {_os_error(exc, ns)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except MemoryError:
        print(
            "error: out of memory; lower the sizes or counts (TACTILE_BENCH_MEMORY_LIMIT sets "
            "the limit the checks use)",
            file=sys.stderr,
        )
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(
            "interrupted: finished stages and training checkpoints are kept; "
            "rerun the same command to resume",
            file=sys.stderr,
        )
        return 130
