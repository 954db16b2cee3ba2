"""``--help`` answers without loading the stack: the parsers are built from light modules,
and each command imports torch, Lightning and the renderer only when it runs (issue 20)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tactile_bench.cli import build_parser, command_paths

#: packages whose import costs seconds; none may load to print a help text
HEAVY = ("torch", "lightning", "torchmetrics", "diffusers", "kornia", "trimesh", "scipy")

_PROBE = """
import contextlib, io, json, sys
from tactile_bench.cli import main
commands = json.loads(sys.argv[1])
codes = {}
for command in commands:
    with contextlib.redirect_stdout(io.StringIO()) as out:
        codes[" ".join(command) or "(top)"] = (main([*command, "--help"]), len(out.getvalue()))
heavy = sorted({m.split(".")[0] for m in sys.modules} & set(json.loads(sys.argv[2])))
print(json.dumps({"codes": codes, "heavy": heavy}))
"""


def test_help_of_every_command_imports_neither_torch_nor_lightning() -> None:
    commands = command_paths(build_parser())
    assert len(commands) > 10  # the walk found the subcommands
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(commands), json.dumps(HEAVY)],
        capture_output=True,
        text=True,
        check=True,
    )
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["heavy"] == [], f"--help imported {report['heavy']}"
    for command, (code, n_chars) in report["codes"].items():
        assert code == 0, command
        assert n_chars > 100, f"{command} --help printed almost nothing"


def test_validate_diagnosis_suites_match_the_module() -> None:
    # the parser is declared in diagnose.commands so that it needs no torch; the suites
    # themselves are diagnose.validate's
    from tactile_bench.diagnose.commands import VALIDATION_SUITES
    from tactile_bench.diagnose.validate import SUITES

    assert (*SUITES, "both") == VALIDATION_SUITES


def test_the_bench_times_every_help_in_a_fresh_process(bench_markdown) -> None:
    from tactile_bench.bench.startup import help_commands, startup_times

    commands = help_commands()
    assert ("--help",) in commands and ("data", "ycb-slide", "--help") in commands
    assert len(commands) == len(command_paths(build_parser()))
    result = startup_times(repeats=1, commands=[("--help",), ("list", "--help")])
    assert [row["command"] for row in result["rows"]] == ["--help", "list --help"]
    assert all(row["median_s"] > 0 for row in result["rows"])
    assert result["slowest_help_s"] == max(row["median_s"] for row in result["rows"])
    table = bench_markdown(startup=result)
    assert "| `list --help` |" in table and "Every `--help` under 1 s" in table


_POLICY_PROBE = """
import contextlib, io, json, os, sys
from tactile_bench.cli import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    code = main(json.loads(sys.argv[1]))
print(json.dumps([code, os.environ.get("OMP_WAIT_POLICY")]))
"""


def _policy_after(command: list[str], env: dict[str, str]) -> tuple[int, str | None]:
    done = subprocess.run(
        [sys.executable, "-c", _POLICY_PROBE, json.dumps(command)],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    code, policy = json.loads(done.stdout.strip().splitlines()[-1])
    return code, policy


def test_openmp_threads_sleep_except_in_the_diagnosis(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    assert _policy_after(["list", "effects"], env) == (0, "PASSIVE")
    missing = str(tmp_path / "no_such_pairs")
    for command in (
        ["diagnose", missing, "--out", str(tmp_path / "out")],
        ["validate-diagnosis", "--out", str(tmp_path / "v"), "--pairs", "-1"],
    ):
        code, policy = _policy_after(command, env)
        assert code != 0 and policy is None, command  # the runtime's spin-then-sleep
    # a setting of the user's own is kept, whatever the command
    assert _policy_after(["list", "effects"], {**env, "OMP_WAIT_POLICY": "ACTIVE"})[1] == "ACTIVE"
