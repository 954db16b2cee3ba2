"""Start-up time of the command line, each command in a fresh interpreter.

What a user waits for at ``python -m tactile_bench X --help`` is a whole process: the
interpreter, the parsers, and whatever they import. The parsers import no torch (command
modules load their machinery when they run; ``tests/test_cli_startup.py``), so every
``--help`` is a fraction of a second; ``list effects`` is here for scale: it needs torch.
Target (issue 20): every ``--help`` under ``TARGET_HELP_S``.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from typing import Any

TARGET_HELP_S = 1.0
#: commands timed beside the help texts: they import what they list
EXTRA: tuple[tuple[str, ...], ...] = (("list", "effects"),)


#: run in a fresh interpreter: every command path of the parser, as JSON. The bench sits
#: below ``cli`` in the layers, so it asks the command line itself rather than import it
_LIST_COMMANDS = (
    "import json; from tactile_bench.cli import build_parser, command_paths; "
    "print(json.dumps(command_paths(build_parser())))"
)


def help_commands() -> list[tuple[str, ...]]:
    """``--help`` of the program and of every command and nested subcommand."""
    out = subprocess.run(
        [sys.executable, "-c", _LIST_COMMANDS], capture_output=True, text=True, check=True
    ).stdout
    return [(*path, "--help") for path in json.loads(out)]


def wall_time(argv: tuple[str, ...]) -> float:
    """Seconds of ``python -m tactile_bench ARGV`` in a new process, output discarded."""
    env = {**os.environ, "WANDB_MODE": "offline"}
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "tactile_bench", *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        check=True,
    )
    return time.perf_counter() - start


def startup_times(
    repeats: int = 3, commands: list[tuple[str, ...]] | None = None
) -> dict[str, Any]:
    """Median wall seconds of each command over ``repeats`` fresh processes, and whether
    every ``--help`` meets the target."""
    commands = commands if commands is not None else [*help_commands(), *EXTRA]
    rows = []
    for argv in commands:
        runs = [wall_time(argv) for _ in range(repeats)]
        rows.append(
            {
                "command": " ".join(argv),
                "median_s": round(statistics.median(runs), 3),
                "runs_s": [round(t, 3) for t in runs],
            }
        )
    helps = [r["median_s"] for r in rows if r["command"].endswith("--help")]
    slowest = max(helps) if helps else None
    return {
        "rows": rows,
        "target_help_s": TARGET_HELP_S,
        "slowest_help_s": slowest,
        "met": slowest is not None and slowest < TARGET_HELP_S,
    }
