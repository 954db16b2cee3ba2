"""The validation layer (tactile_bench.guard): rules cover every argument, YAML is safe,
outputs are checked and locked before the work."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tactile_bench.cli import build_parser, main
from tactile_bench.cli_args import ARG_RULES, OUTPUTS, READ_ONLY
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.outputs import OutputLock, check_output_dir, check_output_file, lock_path
from tactile_bench.guard.safe_yaml import MAX_NODES, load_yaml_file, load_yaml_text

#: argument names that mean an output location: each must be declared in cli_args.OUTPUTS
OUTPUT_DESTS = {"out", "run_dir", "figure", "save_frames"}


def _commands(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, list]:
    """{command name: its actions}, nested subcommands as ``data ycb-slide``."""
    found: dict[str, list] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                full = f"{prefix} {name}".strip()
                found[full] = sub._actions
                found |= _commands(sub, full)
    return found


def test_every_numeric_or_list_argument_of_every_command_has_a_rule() -> None:
    parser = build_parser()
    missing = []
    actions = [("", a) for a in parser._actions]
    actions += [(c, a) for c, acts in _commands(parser).items() for a in acts]
    for command, action in actions:
        numeric = action.type in (int, float)
        listed = action.nargs in ("*", "+") and action.choices is None
        if (numeric or listed) and action.dest not in ARG_RULES:
            missing.append(f"{command} --{action.dest}")
    assert not missing, f"arguments without a rule in cli_args.ARG_RULES: {missing}"


def test_every_output_argument_is_declared() -> None:
    undeclared = [
        (command, a.dest)
        for command, acts in _commands(build_parser()).items()
        for a in acts
        if a.dest in OUTPUT_DESTS and (command, a.dest) not in OUTPUTS.keys() | READ_ONLY
    ]
    assert not undeclared, f"declare these in cli_args.OUTPUTS: {undeclared}"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("a: 1\nb: 2\na: 3\n", "key 'a' written twice"),
        (
            "x: &a [1, 2]\ny: &b [*a, *a]\n"
            + "".join(
                f"l{i}: &l{i} [{', '.join([f'*{p}'] * 10)}]\n"
                for i, p in enumerate(["b", "l0", "l1", "l2", "l3"])
            ),
            "alias bomb",
        ),
        ("a: &x [1, *x]\n", "recursive alias"),
        ("[" * 5000, "nested too deeply"),
        ("\x00", "not valid YAML"),
        ("a: [1,\n", "not valid YAML"),
    ],
)
def test_unsafe_yaml_is_refused_in_one_line(text: str, words: str) -> None:
    with pytest.raises(TactileBenchError) as info:
        load_yaml_text(text, "r.yaml")
    message = str(info.value)
    assert words in message and message.startswith("r.yaml") and "\n" not in message


def test_yaml_merge_keys_and_small_aliases_still_load() -> None:
    text = "base: &b {x: 1, y: 2}\nstage: {<<: *b, y: 3}\nlist: [*b, *b]\n"
    assert load_yaml_text(text, "r.yaml")["stage"] == {"x": 1, "y": 3}
    assert MAX_NODES >= 10_000


def test_a_fifo_recipe_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "recipe.yaml"
    os.mkfifo(fifo)
    start = time.perf_counter()
    with pytest.raises(TactileBenchError, match="FIFO"):
        load_yaml_file(fifo, "recipe")
    assert time.perf_counter() - start < 1.0


def test_output_checks_find_files_and_read_only_folders(tmp_path: Path) -> None:
    file = tmp_path / "f.txt"
    file.write_text("x")
    with pytest.raises(TactileBenchError, match="exists and is not a folder"):
        check_output_dir(file, "--out")
    with pytest.raises(TactileBenchError, match="which is a file"):
        check_output_dir(file / "sub" / "dir", "--out")
    with pytest.raises(TactileBenchError, match=r"give a file name ending in \.png"):
        check_output_file(tmp_path / "sheet.jpg", "--out", (".png",))
    with pytest.raises(TactileBenchError, match="is a folder"):
        check_output_file(tmp_path, "--out", ())
    assert check_output_dir(tmp_path / "new" / "deeper", "--out") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checked, not created
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]  # the probe file is gone
    if os.geteuid() != 0:  # root writes anywhere; the probe then rightly passes
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        with pytest.raises(TactileBenchError, match="cannot write"):
            check_output_dir(ro / "out", "--out")


def test_a_second_holder_is_refused_naming_the_first_and_a_dead_ones_lock_is_taken(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    target = tmp_path / "run"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from tactile_bench.guard.outputs import OutputLock\n"
            f"with OutputLock({str(target)!r}, '--out'):\n"
            "    print('held', flush=True); time.sleep(30)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(TactileBenchError) as info:
            OutputLock(target, "--out").acquire()
        assert f"in use by process {holder.pid}" in str(info.value)
    finally:
        holder.kill()  # a killed run: its flock goes, its lock file stays
        holder.wait()
    assert json.loads(lock_path(target).read_text())["pid"] == holder.pid
    with caplog.at_level("WARNING", logger="tactile_bench"), OutputLock(target, "--out"):
        assert "taking over the lock left by process" in caplog.text
    assert not lock_path(target).exists()


def test_cli_usage_errors_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--threads", "many", "list"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "--threads" in err and len(err.splitlines()) == 1


def test_a_plugin_calling_sys_exit_is_marked_broken(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from importlib.metadata import EntryPoint

    from tactile_bench.translators import registry

    (tmp_path / "exits_on_import.py").write_text("import sys\nsys.exit(3)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    real = registry.entry_points

    def with_exiting(group: str) -> list:
        return [*real(group=group), EntryPoint("quitter", "exits_on_import:T", group)]

    monkeypatch.setattr(registry, "entry_points", with_exiting)
    assert main(["list", "translators"]) == 0
    out = capsys.readouterr().out
    assert "quitter" in out and "SystemExit: 3" in out and "cgan" in out


def test_the_working_folder_is_locked_from_inside(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert lock_path(Path(".")) == tmp_path / ".tactile_bench.lock"
    assert lock_path(Path("out")) == tmp_path / ".out.tactile_bench.lock"
    with OutputLock(Path("."), "--out"):
        assert (tmp_path / ".tactile_bench.lock").exists()
    assert not any(tmp_path.parent.glob(f".{tmp_path.name}*"))


def test_fit_on_a_run_dir_another_process_holds_is_refused_before_any_stage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: held\nstages:\n  - {name: braille, kind: braille_data, config: {chars: AB, "
        "n_finetune: 4, n_test: 4, n_classifier: 4, n_classifier_test: 4}}\n"
    )
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time; from tactile_bench.guard.outputs import OutputLock\n"
            f"with OutputLock({str(run)!r}, 'run dir'):\n"
            "    print('held', flush=True); time.sleep(30)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        capsys.readouterr()
        assert main(["fit", str(recipe), "--run-dir", str(run), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"run dir {run}: in use by process {holder.pid}" in err
        assert not run.exists()  # no stage started
    finally:
        holder.kill()
        holder.wait()
