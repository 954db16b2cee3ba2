"""Feed the real command line every kind of bad input a messy folder holds; tabulate what it said.

    python scripts/bad_inputs.py [--out docs/results/bad_inputs.md] [--only KIND ...]

Each case builds its bad input in a temporary folder, runs ``python -m tactile_bench ...`` as
a subprocess (as a user would) and records the exit code, the error line and whether a
traceback appeared. A case that exits 0 where it should fail, or prints a traceback, is a bug.
The cases live in ``bad_input_cases.CASES`` (fixtures in ``bad_input_fixtures``), so
tests/test_reliability_bad_inputs.py runs a fast subset in-process through
``tactile_bench.cli.main``.
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from bad_input_cases import CASES, Case

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- running
@dataclass
class Outcome:
    """What one command printed: exit code, its error line, whether a traceback showed."""

    case: Case
    command: str
    code: int
    line: str
    traceback: bool
    seconds: float

    @property
    def ok(self) -> bool:
        names = self.case.names in self.line if self.case.names else True
        return self.code == self.case.expect_exit and not self.traceback and names


def error_line(stderr: str, stdout: str = "") -> str:
    """The ``error:`` line the CLI prints (stderr also carries log lines and library noise)."""
    for line in stderr.splitlines():
        if line.startswith(("error:", "interrupted:")):
            return line
    lines = [line for line in stdout.splitlines() if "broken" in line] or stdout.splitlines()
    return lines[0].strip() if lines else (stderr.strip().splitlines() or [""])[0]


def run(case: Case, tmp: Path) -> Outcome:
    """Build the case under ``tmp`` and run the real CLI on it in a subprocess."""
    args = case.build(tmp)
    env = dict(os.environ, TACTILE_BENCH_NO_WANDB="1", WANDB_MODE="offline")
    if case.env is not None:
        env |= case.env(tmp)
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "tactile_bench", "--threads", "1", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=600,
    )
    shown = " ".join(a.replace(str(tmp), "$TMP") for a in args)
    if "Traceback (most recent call last)" in proc.stderr:
        print(proc.stderr[-2000:], file=sys.stderr)  # a bug: show where
    return Outcome(
        case,
        f"tactile_bench {shown}",
        proc.returncode,
        error_line(proc.stderr, proc.stdout).replace(str(tmp), "$TMP"),
        "Traceback (most recent call last)" in proc.stderr + proc.stdout,
        time.perf_counter() - start,
    )


def table(outcomes: list[Outcome]) -> str:
    """The markdown table of docs/results/bad_inputs.md."""
    rows = [
        "| # | class | bad input | command | exit | error line (stderr) | traceback? | "
        "as expected? |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for i, o in enumerate(outcomes, 1):
        line = o.line.replace("|", "\\|")
        command = o.command.replace("|", "\\|")
        rows.append(
            f"| {i} | {o.case.group} | {o.case.kind} | `{command}` | {o.code} | {line} | "
            f"{'yes' if o.traceback else 'no'} | {'yes' if o.ok else '**NO**'} |"
        )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "docs/results/bad_inputs.md"))
    parser.add_argument("--only", nargs="*", help="case kinds containing these words")
    ns = parser.parse_args(argv)
    cases = [c for c in CASES if not ns.only or any(w in c.kind for w in ns.only)]
    outcomes = []
    for case in cases:
        with tempfile.TemporaryDirectory() as tmp:
            outcome = run(case, Path(tmp))
        flag = "ok " if outcome.ok else "BAD"
        print(f"{flag} {outcome.code:>3} {outcome.seconds:5.1f} s  {case.kind}: {outcome.line}")
        outcomes.append(outcome)
    bad = [o for o in outcomes if not o.ok]
    groups: dict[str, list[Outcome]] = {}
    for o in outcomes:
        groups.setdefault(o.case.group, []).append(o)
    summary = "\n".join(
        f"| {name} | {len(rows)} | {sum(not o.ok for o in rows)} | "
        f"{max(o.seconds for o in rows):.1f} s |"
        for name, rows in groups.items()
    )
    header = (
        "# Bad inputs: what the command line says\n\n"
        "Made by `python scripts/bad_inputs.py` (each case is built in a temporary folder, "
        "`$TMP`, and run as a subprocess; `--threads 1`). Expected: exit code 2, one `error:` "
        "line naming the file or key at fault, no traceback; `list` with broken plugins "
        f"exits 0 and marks them. {len(outcomes)} kinds, {len(bad)} not as expected.\n\n"
        "Every refusal comes from `tactile_bench.guard` before any work (argument rules by "
        "name, memory and disk estimates, output checks and locks, the safe YAML loader, "
        "image headers), from the readers' own checks, or from the CLI's last line of "
        "defence (an `OSError` or `MemoryError` is one line too). The slowest answer is "
        "the interpreter importing torch on a loaded 2-core machine.\n\n"
        "| class | kinds | not as expected | slowest answer |\n| --- | --- | --- | --- |\n"
        f"{summary}\n\n"
    )
    buffer = io.StringIO()
    buffer.write(header + table(outcomes))
    out = Path(ns.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = out.with_suffix(".md.tmp")
    tmp_out.write_text(buffer.getvalue())
    tmp_out.replace(out)
    print(f"wrote {out}: {len(outcomes)} cases, {len(bad)} not as expected")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
