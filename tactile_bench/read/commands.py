"""Subcommand ``read``: slide a DIGIT along a braille label strip and read the word."""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import sys
from pathlib import Path

from tactile_bench.errors import TactileBenchError


def _import_pybullet_to_stderr() -> None:
    """Import pybullet with file descriptor 1 pointed at stderr: its C code prints a build
    line on stdout at import (flushed at exit), which would corrupt ``--json`` output."""
    if "pybullet" in sys.modules:
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        import pybullet  # noqa: F401

        ctypes.CDLL(None).fflush(None)  # the C buffer goes out while fd 1 is still stderr
    except (OSError, AttributeError):
        pass  # no libc to flush (not POSIX): the line may still reach stdout
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _cmd_read(ns: argparse.Namespace) -> int:
    import torch

    from tactile_bench.geometry.braille import CHARACTERS
    from tactile_bench.read.reader import (
        aggregate,
        find_model,
        format_reading,
        frame_log_probs,
        load_model,
        summary,
    )
    from tactile_bench.read.strip import build_strip, check_word, render_frames
    from tactile_bench.sensor.depth import GelSpec
    from tactile_bench.sensor.surrogate import SurrogateDigit

    word = check_word(ns.word)
    if ns.model is not None and ns.row is not None:
        raise TactileBenchError("--model and --row: give one (--row picks a model in --run-dir)")
    model_path = (
        Path(ns.model) if ns.model else find_model(ns.run_dir, ns.row or "diffusion", ns.model_seed)
    )
    sensor = SurrogateDigit.from_profile(ns.profile)
    model = load_model(model_path)
    gel = GelSpec()
    _import_pybullet_to_stderr()
    strip = build_strip(word, gel=gel, pitch_mm=ns.pitch_mm)
    x_mm = strip.travel_mm(ns.step_mm)
    generator = torch.Generator().manual_seed(ns.seed)
    frames = render_frames(strip, x_mm, sensor, ns.press_mm, gel, generator)
    log_probs = frame_log_probs(model, frames.foreground())
    classes = CHARACTERS[: log_probs.shape[1]]
    readings = aggregate(log_probs, frames.x_mm, strip.cell_x_mm, strip.pitch_mm, word, classes)
    settings = {
        "model": str(model_path),
        "profile": ns.profile,
        "seed": ns.seed,
        "press_mm": ns.press_mm,
        "step_mm": ns.step_mm,
    }
    result = summary(readings, log_probs, frames.x_mm, strip.pitch_mm, classes, settings)
    if ns.save_frames:
        from tactile_bench.read.figure import strip_figure_png

        title = f"read {result['read']} (true {word}) with {model_path.parent.name}"
        result["figure"] = str(
            strip_figure_png(strip, frames, readings, ns.save_frames, title, gel)
        )
    if ns.json:
        print(json.dumps(result, indent=2))
    else:
        print("\n".join(format_reading(result)))
        if ns.save_frames:
            print(f"wrote {result['figure']}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``read``: the paper's demo of reading a word from a braille label."""
    read = subparsers.add_parser(
        "read",
        help="slide the sensor along a braille label strip and read the word with a classifier",
        description=(
            "Render a braille label strip of --word (cells at 2.7 x the dot spacing), slide a "
            "surrogate DIGIT along it, classify every frame and read each cell from the frames "
            "within a quarter pitch of its centre (mean log-probability)."
        ),
    )
    read.add_argument(
        "--word", default="DIGIT", help="braille characters A-Z and # (default DIGIT)"
    )
    read.add_argument("--model", help="a classify stage's model_seed{n}.pt (default: --run-dir)")
    read.add_argument(
        "--run-dir",
        default="runs/table1",
        help="run directory whose classify stage of --row gives the model (default runs/table1)",
    )
    read.add_argument(
        "--row", help="table row whose model reads, e.g. sim, real (default diffusion)"
    )
    read.add_argument("--model-seed", type=int, default=0, help="which seed's model (default 0)")
    read.add_argument("--profile", default="digit", help="surrogate profile name or YAML path")
    read.add_argument("--press-mm", type=float, default=0.6, help="press depth (mm, default 0.6)")
    read.add_argument("--step-mm", type=float, default=1.0, help="frame spacing (mm, default 1)")
    read.add_argument("--pitch-mm", type=float, help="cell pitch (default 2.7 x dot spacing)")
    read.add_argument("--seed", type=int, default=0, help="seed of the sensor's randomness")
    read.add_argument("--json", action="store_true", help="print the reading as JSON")
    read.add_argument("--save-frames", metavar="PNG", help="write a figure of the frames read")
    read.set_defaults(func=_cmd_read)
