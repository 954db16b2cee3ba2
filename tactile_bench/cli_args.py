"""Which rule each command-line argument follows, checked after parsing and before any work.

Each numeric argument is checked by its name (``dest``), whatever command it belongs to:
a new command's ``--seed`` or ``--size`` is covered the day it is added, and a test fails
when an argument has no rule. :data:`OUTPUTS` declares each command's output arguments
(folder or file, which suffixes, locked or not); :data:`ESTIMATES` each command's memory
and disk estimate from its sizes and counts. The rule kinds and bounds are
``guard.args``'s; this table knows the commands and the domain their estimates need.
"""

from __future__ import annotations

import argparse
import contextlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.args import (
    BYTES_PER_PAIR_PIXEL,
    DISK_PER_PAIR_PIXEL,
    MAX_SIZE,
    MIN_SIZE,
    Count,
    Names,
    Output,
    Real,
    Rule,
    Seed,
    Text,
    YamlFile,
    flag,
)
from tactile_bench.guard.files import require_not_special
from tactile_bench.guard.limits import check_disk, check_memory
from tactile_bench.guard.outputs import OutputLock, check_output_dir, check_output_file

#: every numeric or list argument of every command, by its ``dest``
ARG_RULES: dict[str, Rule] = {
    "threads": Count(1, 1024),
    "jobs": Count(1, 64),
    "seed": Seed(),
    "model_seed": Count(0, 1_000_000),
    "size": Count(MIN_SIZE, MAX_SIZE),
    "pairs": Count(10),
    "generate": Count(1),
    "max_pairs": Count(4),  # the diagnosis needs 4 pairs (run.MIN_PAIRS)
    "pretrain_pairs": Count(10),
    "pretrain_steps": Count(1),
    "finetune_steps": Count(1),
    "cgan_steps": Count(1),
    "repeats": Count(1, 10_000),
    "ddpm_images": Count(1),
    "fit_fraction": Real(0.0, 1.0),
    "holdout": Real(0.0, 1.0, closed_low=True),  # calibrate: 0 fits on every pair
    "press_mm": Real(0.0, 3.0, closed_high=True, unit="mm (the gel is about 2 mm thick)"),
    "step_mm": Real(0.0, 24.0, closed_high=True, unit="mm"),
    "pitch_mm": Real(0.0, 24.0, closed_high=True, unit="mm"),
    "chars": Names(nonempty=False),
    "objects": Names(nonempty=False),
    "candidates": Names(),
    "only": Names(),
    "force": Names(nonempty=False),
    "word": Text(200),
    "recipe": YamlFile("recipe"),
    "profile": YamlFile("profile", named=True),
}


#: each command's output arguments: (command, dest) -> Output. ``fit``'s run dir comes from
#: its recipe, so the runner checks and locks it (``pipeline.runner``).
OUTPUTS: dict[tuple[str, str], Output] = {
    ("diagnose", "out"): Output(folder=True),
    ("calibrate", "out"): Output(folder=True),
    ("export-pairs", "out"): Output(folder=True),
    ("data ycb-slide", "out"): Output(folder=True),
    ("render", "out"): Output(folder=False, suffixes=(".png",)),
    ("ground", "figure"): Output(folder=False, suffixes=(".png",)),
    ("real-translators", "out"): Output(folder=True),
    ("validate-diagnosis", "out"): Output(folder=True),
    ("bench", "out"): Output(folder=True),
    ("read", "save_frames"): Output(folder=False, suffixes=(".png",)),
    ("fit", "run_dir"): Output(folder=True, lock=False),
}

#: each command's input arguments an output folder must not hold (or be)
INPUTS: dict[str, tuple[str, ...]] = {
    "diagnose": ("paired_dir",),
    "calibrate": ("paired_dir",),
    "export-pairs": ("source",),
    "bench": ("diffusion", "braille"),
}


def _check_not_holding_inputs(ns: argparse.Namespace, command: str, out: str, key: str) -> None:
    """An output folder that is an input, or holds one, would be overwritten (or with
    ``--overwrite``, deleted) by the work: refused."""
    target = Path(os.path.abspath(out))
    for dest in INPUTS.get(command, ()):
        value = getattr(ns, dest, None)
        if not value:
            continue
        source = Path(os.path.abspath(value))
        if target == source or target in source.parents:
            raise TactileBenchError(
                f"{key} {out}: holds the input {value}; writing there would overwrite it"
            )


#: arguments named like outputs that a command only reads
READ_ONLY: frozenset[tuple[str, str]] = frozenset({("read", "run_dir")})


def command_name(ns: argparse.Namespace) -> str:
    """``data ycb-slide`` for a nested subcommand, else the command."""
    sub = getattr(ns, "dataset", None)
    return f"{ns.command} {sub}" if sub else str(ns.command)


# ----------------------------------------------------------------------------- estimates
def _pairs_estimate(key: str, n: int, size: int, out: str | None) -> None:
    pixels = float(n) * size * size
    what = f"{n} pairs of {size} x {size} pixels"
    check_memory(key, what, pixels * BYTES_PER_PAIR_PIXEL)
    if out is not None:
        check_disk(key, what, pixels * DISK_PER_PAIR_PIXEL, Path(out))


#: the most presses a real-press set holds (taxim's GelSight pack: 48)
MAX_REAL_PRESSES = 48


def _export_pairs(ns: argparse.Namespace) -> None:
    if ns.generate is not None:
        _pairs_estimate(f"--generate {ns.generate} --size {ns.size}", ns.generate, ns.size, ns.out)
    elif ns.real_presses is not None:
        _pairs_estimate(f"--size {ns.size}", MAX_REAL_PRESSES, ns.size, ns.out)


def _read(ns: argparse.Namespace) -> None:
    """Frames of the slide: the strip's length over the step, each a 64 x 64 contact."""
    # trimesh and torch: imported for `read` only, so `--help` stays fast
    from tactile_bench.geometry.braille import BrailleSpec
    from tactile_bench.read.strip import CELL_PITCH_RATIO

    pitch = ns.pitch_mm or CELL_PITCH_RATIO * BrailleSpec().dot_spacing_mm
    frames = (len(ns.word) + 2) * pitch / ns.step_mm
    what = f"{frames:.0f} frames ({len(ns.word)} cells of {pitch:g} mm every {ns.step_mm:g} mm)"
    check_memory("--word, --step-mm", what, frames * 64 * 64 * BYTES_PER_PAIR_PIXEL)


def _data_ycb(ns: argparse.Namespace) -> None:
    if ns.pairs is not None:
        _pairs_estimate(f"--pairs {ns.pairs}", ns.pairs, 64, ns.out)


def _validate_diagnosis(ns: argparse.Namespace) -> None:
    if ns.pairs is not None:
        _pairs_estimate(f"--pairs {ns.pairs} --size {ns.size}", ns.pairs, ns.size, None)


def _real_translators(ns: argparse.Namespace) -> None:
    _pairs_estimate(f"--pretrain-pairs {ns.pretrain_pairs}", ns.pretrain_pairs, 64, ns.out)


def _render(ns: argparse.Namespace) -> None:
    if not ns.chars and not ns.objects:
        raise TactileBenchError("--chars, --objects: both empty; give at least one of them")


#: what each command would allocate or write, from its arguments
ESTIMATES: dict[str, Callable[[argparse.Namespace], None]] = {
    "export-pairs": _export_pairs,
    "data ycb-slide": _data_ycb,
    "validate-diagnosis": _validate_diagnosis,
    "real-translators": _real_translators,
    "render": _render,
    "read": _read,
}


def check_arguments(ns: argparse.Namespace) -> None:
    """Every rule that applies to ``ns``: values, then estimates, then outputs.

    A count above its bound is reported after the command's memory estimate, so an absurd
    size says what it would have allocated against the limit.
    """
    for dest, value in vars(ns).items():  # a FIFO or device given for any path blocks
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, str) and item:
                require_not_special(item, flag(dest).lstrip("-").replace("-", " "))
    too_large: TactileBenchError | None = None
    for dest, value in vars(ns).items():
        rule = ARG_RULES.get(dest)
        if rule is None or value is None:
            continue
        try:
            rule(dest, value)
        except TactileBenchError as exc:
            above = isinstance(rule, Count) and isinstance(value, int) and value > rule.high
            if not above:
                raise
            too_large = too_large or exc
    command = command_name(ns)
    estimate = ESTIMATES.get(command)
    if estimate is not None:
        estimate(ns)
    if too_large is not None:
        raise too_large
    for (cmd, dest), spec in OUTPUTS.items():
        value = getattr(ns, dest, None)
        if cmd != command or value is None:
            continue
        if spec.folder:
            _check_not_holding_inputs(ns, command, value, flag(dest))
            check_output_dir(value, flag(dest))
        else:
            check_output_file(value, flag(dest), spec.suffixes)


def output_of(ns: argparse.Namespace) -> Path | None:
    """The command's first declared output argument's path, or None when it has none."""
    command = command_name(ns)
    for (cmd, dest), _spec in OUTPUTS.items():
        value = getattr(ns, dest, None)
        if cmd == command and value is not None:
            return Path(value)
    return None


@contextlib.contextmanager
def output_locks(ns: argparse.Namespace) -> Iterator[None]:
    """Hold the locks of the command's locked outputs while it runs."""
    command = command_name(ns)
    with contextlib.ExitStack() as stack:
        for (cmd, dest), spec in OUTPUTS.items():
            value = getattr(ns, dest, None)
            if cmd == command and spec.lock and value is not None:
                stack.enter_context(OutputLock(Path(value), flag(dest)))
        yield


def check_environment() -> None:
    """Settings of the environment that would fail only after the work (a wandb login)."""
    if os.environ.get("WANDB_MODE", "").strip().lower() != "online":
        return
    from tactile_bench.pipeline.loggers import wandb_enabled  # imports Lightning: only now

    if not wandb_enabled():
        return
    if os.environ.get("WANDB_API_KEY"):
        return
    netrc = Path(os.environ.get("NETRC", Path.home() / ".netrc"))
    try:
        if "api.wandb.ai" in netrc.read_text():
            return
    except OSError:
        pass
    raise TactileBenchError(
        "WANDB_MODE=online: no wandb API key (set WANDB_API_KEY or run `wandb login`), or "
        "unset WANDB_MODE to log offline, or set TACTILE_BENCH_NO_WANDB=1"
    )
