"""A bad recipe fails before any work: one line naming file and key, exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactile_bench.cli import main

GOOD = """
name: t
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 4, n_test: 4}
  - name: tr
    kind: translate
    inputs: {data: braille}
    config: {translator: sim}
"""

CASES = {
    "unknown top-level key": (GOOD.replace("name: t\n", "name: t\nseeds: 3\n"), "seeds"),
    "unknown stage config key": (GOOD.replace("n_test: 4", "n_test: 4, n_tset: 3"), "n_tset"),
    "wrong type": (GOOD.replace("n_test: 4", "n_test: many"), "n_test"),
    "out of range": (GOOD.replace("n_test: 4", "n_test: -1"), "n_test"),
    "unknown translator": (GOOD.replace("translator: sim", "translator: nope"), "translator"),
    "unknown stage kind": (GOOD.replace("kind: translate", "kind: translat"), "kind"),
    "input not earlier": (GOOD.replace("data: braille", "data: later"), "inputs.data"),
    "missing input": (GOOD.replace("inputs: {data: braille}", "inputs: {}"), "inputs.data"),
    "not a character": (GOOD.replace("chars: AB", "chars: A!"), "chars"),
    "unknown sensor": (
        GOOD.replace("n_test: 4}", "n_test: 4, real_sensor: nosuch}"),
        "real_sensor",
    ),
    "unknown second unit": (
        GOOD.replace("n_test: 4}", "n_test: 4, second_unit: nosuch}"),
        "second_unit",
    ),
    "second unit of real data": (
        GOOD.replace("n_test: 4}", "n_test: 4, source: /nonexistent, second_unit: digit-b}"),
        "second_unit: needs source: surrogate",
    ),
    "bad yaml": ("name: [t\nstages: -", "YAML"),
    "no stages": ("name: t\nstages: []\n", "stages"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_recipe_is_one_line_naming_file_and_key(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text, key = CASES[case]
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    run_dir = tmp_path / "run"
    code = main(["fit", str(path), "--run-dir", str(run_dir), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    assert str(path) in err and key in err, err
    assert not run_dir.exists()


def test_missing_recipe_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["fit", str(tmp_path / "absent.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and "absent.yaml" in err and "not found" in err


def test_set_override_is_validated(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "r.yaml"
    path.write_text(GOOD)
    code = main(
        ["fit", str(path), "--set", "braille.n_test=oops", "--run-dir", str(tmp_path / "x")]
    )
    assert code == 2 and "n_test" in capsys.readouterr().err
    code = main(["fit", str(path), "--set", "nosuchstage.a=1"])
    assert code == 2 and "nosuchstage" in capsys.readouterr().err


def test_unknown_force_stage(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "r.yaml"
    path.write_text(GOOD)
    code = main(["fit", str(path), "--force", "ghost", "--run-dir", str(tmp_path / "x")])
    assert code == 2 and "ghost" in capsys.readouterr().err
