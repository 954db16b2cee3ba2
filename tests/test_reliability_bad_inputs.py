"""The bad inputs of scripts/bad_inputs.py, run in-process: exit 2, one error line naming the
file or key at fault, no traceback. (The script runs all of them as subprocesses and writes
docs/results/bad_inputs.md.)"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from tactile_bench.cli import main
from tactile_bench.translators import registry

REPO = Path(__file__).resolve().parents[1]


def _load(name: str) -> ModuleType:
    """A module of scripts/ (they import each other by name, as ``python scripts/x.py`` does)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


_load("bad_input_fixtures")
_load("bad_input_guard_cases")
SCRIPT = _load("bad_input_cases")
FAST = {c.kind: c for c in SCRIPT.CASES if not c.slow and c.env is None}


def test_the_script_covers_at_least_twenty_kinds() -> None:
    assert len(SCRIPT.CASES) >= 20 and len(FAST) >= 20


def test_every_class_of_issue_23_has_many_kinds() -> None:
    groups: dict[str, int] = {}
    for case in SCRIPT.CASES:
        groups[case.group] = groups.get(case.group, 0) + 1
    assert len(SCRIPT.CASES) >= 100
    assert len(groups) >= 7 and min(groups.values()) >= 8, groups


@pytest.mark.parametrize("kind", sorted(FAST))
def test_bad_input_is_one_line_naming_the_file(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TACTILE_BENCH_NO_WANDB", "1")
    case = FAST[kind]
    args = case.build(tmp_path)
    capsys.readouterr()
    code = main(args)
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == case.expect_exit == 2
    assert len(errors) == 1, err
    assert case.names in errors[0], errors[0]
    assert "Traceback" not in err


def test_broken_plugins_break_neither_list_nor_other_translators(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    real = registry.entry_points

    def with_broken(group: str) -> list:
        from importlib.metadata import EntryPoint

        extra = [
            EntryPoint("broken", "no_such_module_xyz:Thing", group),
            EntryPoint("notone", "json:dumps", group),
        ]
        return [*real(group=group), *extra]

    monkeypatch.setattr(registry, "entry_points", with_broken)
    assert main(["list", "translators"]) == 0
    out = capsys.readouterr().out
    assert "failed to import" in out and "not a Translator" in out and "cgan" in out
    for name in ("plugin that fails to import", "plugin that is not a Translator"):
        case = next(c for c in SCRIPT.CASES if c.kind == name)
        folder = tmp_path / name.replace(" ", "_")
        folder.mkdir()
        assert main(case.build(folder)) == 2
        err = capsys.readouterr().err
        assert case.names in err and "Traceback" not in err
    assert registry.translator_class("sim").name == "sim"  # the others still load


def test_skip_bad_reports_what_was_skipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = SCRIPT.braille_layout(tmp_path / "td", per_letter=3)
    (root / "real_fine_tuning/color/a/a_1.png").write_bytes(b"\x89PNG cut")
    SCRIPT.png(root / "real_fine_tuning/color/b/b_9.png", SCRIPT.frame(1))  # unpaired
    assert main(["check", str(root)]) == 2
    capsys.readouterr()
    assert main(["check", str(root), "--skip-bad"]) == 0
    out = capsys.readouterr().out
    assert "ok:" in out and "5 fine-tuning pairs" in out and "skipped" in out
    assert "a_1.png" in out and "b_9.png" in out
