"""The smoke recipe end to end, in-process, and the listings."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from tactile_bench.cli import main


def test_smoke_recipe_end_to_end(
    repo: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run_dir = tmp_path / "smoke"
    args = ["fit", str(repo / "recipes" / "smoke.yaml"), "--run-dir", str(run_dir), "--no-progress"]
    assert main(args) == 0
    out = capsys.readouterr().out
    results = json.loads((run_dir / "results.json").read_text())
    (row,) = results["rows"]
    assert row["row"] == "sim"
    for metric in ("accuracy", "precision", "recall"):
        assert 0.0 <= row[metric]["mean"] <= 1.0
    assert row["extra"]["n_test"] == 60
    assert 0.0 <= row["sim_accuracy"]["mean"] <= 1.0
    ablation = (run_dir / "ablation.md").read_text()
    assert "optical_response" in ablation and "all effects off" in ablation
    assert (run_dir / "results.md").read_text() in out  # the table is printed
    assert list(run_dir.glob("braille-*/preview.png"))

    start = time.perf_counter()
    assert main(args) == 0  # finished: nothing is redone
    assert time.perf_counter() - start < 20
    assert "cached" in capsys.readouterr().out


def test_list_everything(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for word in ("sim", "colour_match", "braille_data", "classify", "effects"):
        assert word in out


def test_help(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    assert "fit" in capsys.readouterr().out
    assert main(["fit", "--help"]) == 0
    assert "--force" in capsys.readouterr().out


def test_render_contact_sheet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sheet.png"
    assert main(["render", "--chars", "A", "#", "--objects", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["render", "--chars", "a"]) == 2
    assert "--chars" in capsys.readouterr().err


def test_ground_against_real_measurements(capsys: pytest.CaptureFixture[str]) -> None:
    from tactile_bench.sensor.grounding import default_real_dir

    if default_real_dir() is None:
        pytest.skip("no ../shared/real reference folder on this machine")
    assert main(["ground"]) == 0
    out = capsys.readouterr().out
    assert "background (digit)" in out and "optical response" in out
    assert main(["ground", "--real-dir", "/nonexistent"]) == 2


@pytest.mark.parametrize("argv", [["list", "effects"], ["--help"], ["diagnose", "--help"]])
def test_a_reader_that_leaves_early_is_not_an_error(argv: list[str]) -> None:
    """``list effects | head -1``: the pipe closes before the listing (or page) is written."""
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "tactile_bench", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # closed long before the process has imported anything
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and b"Traceback" not in err and b"BrokenPipe" not in err


def test_a_closed_stdout_is_not_an_error() -> None:
    """``list effects >&-``: Python starts with ``sys.stdout`` None; the listing goes nowhere."""
    import os
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "tactile_bench", "list", "effects"],
        stdout=None,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: os.close(1),
        timeout=120,
    )
    assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr.decode()


def test_a_missing_dependency_is_the_install_line_not_a_traceback() -> None:
    """``list effects`` in a Python without torch (a clone run before installing it)."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['torch'] = None\n"  # `import torch` now fails as if absent
        "from tactile_bench.cli import main; sys.exit(main(['list', 'effects']))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    err = proc.stderr.decode()
    assert proc.returncode == 2 and "Traceback" not in err, err
    assert "'torch' is not installed" in err and "pip install" in err
