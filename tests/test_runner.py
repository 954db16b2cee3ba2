"""The recipe runner's cache: reruns skip, --force redoes, corruption and kills rebuild."""

from __future__ import annotations

import errno
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from tactile_bench.io import atomic_write_npz
from tactile_bench.pipeline import stages as stage_registry
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.pipeline.runner import DONE, run_recipe
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.training import fingerprint
from tests.test_pipeline_memory import allocate_above_peak

CALLS: list[str] = []


class CountConfig(StageConfig):
    value: int = 1


def _produce(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    CALLS.append(ctx.name)
    upstream = sum(int(r.path("out").read_text()) for rs in ctx.inputs.values() for r in rs)
    (ctx.directory / "out.txt").write_text(str(ctx.config.value + upstream))
    return {"out": "out.txt"}, {"value": ctx.config.value + upstream}


@pytest.fixture
def recipe_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setitem(
        stage_registry.STAGES,
        "count",
        StageKind("count", "test stage", CountConfig, _produce, {"up": False}),
    )
    CALLS.clear()
    path = tmp_path / "r.yaml"
    path.write_text(
        f"name: r\nrun_dir: {tmp_path / 'run'}\nstages:\n"
        "  - {name: a, kind: count, config: {value: 2}}\n"
        "  - {name: b, kind: count, inputs: {up: a}, config: {value: 3}}\n"
    )
    return path


def test_rerun_does_no_work(recipe_path: Path) -> None:
    first = run_recipe(load_recipe(recipe_path))
    assert CALLS == ["a", "b"] and first[-1].metrics["value"] == 5
    second = run_recipe(load_recipe(recipe_path))
    assert CALLS == ["a", "b"]
    assert all(r.cached for r in second)


def test_force_redoes_one_stage(recipe_path: Path) -> None:
    run_recipe(load_recipe(recipe_path))
    run_recipe(load_recipe(recipe_path), force=("b",))
    assert CALLS == ["a", "b", "b"]


def test_config_change_reruns_downstream_only(recipe_path: Path) -> None:
    run_recipe(load_recipe(recipe_path))
    results = run_recipe(load_recipe(recipe_path, ["b.value=10"]))
    assert CALLS == ["a", "b", "b"] and results[-1].metrics["value"] == 12
    results = run_recipe(load_recipe(recipe_path, ["a.value=4"]))
    assert CALLS == ["a", "b", "b", "a", "b"] and results[-1].metrics["value"] == 7


def test_corrupted_output_is_rebuilt(recipe_path: Path) -> None:
    first = run_recipe(load_recipe(recipe_path))
    first[0].path("out").write_text("999")
    second = run_recipe(load_recipe(recipe_path))
    assert CALLS == ["a", "b", "a"]
    assert second[0].metrics["value"] == 2 and not second[0].cached
    assert second[1].cached  # a's content is back to what b was built from


def test_killed_stage_resumes(recipe_path: Path) -> None:
    first = run_recipe(load_recipe(recipe_path))
    (first[1].directory / DONE).unlink()  # as if killed before b finished
    run_recipe(load_recipe(recipe_path))
    assert CALLS == ["a", "b", "b"]


def test_run_json_records_stages(recipe_path: Path, tmp_path: Path) -> None:
    run_recipe(load_recipe(recipe_path))
    text = (tmp_path / "run" / "run.json").read_text()
    assert '"a"' in text and '"wall_time_s"' in text


def _allocate(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    blocks = allocate_above_peak(ctx.config.value)
    (ctx.directory / "out.txt").write_text(str(int(blocks[0][0])))
    return {"out": "out.txt"}, {}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_stage_that_raised_the_peak_memory_is_on_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(
        stage_registry.STAGES,
        "allocate",
        StageKind("allocate", "test stage", CountConfig, _allocate, {}),
    )
    path = tmp_path / "m.yaml"
    path.write_text(
        f"name: m\nrun_dir: {tmp_path / 'run'}\nstages:\n"
        "  - {name: small, kind: allocate, config: {value: 0}}\n"
        "  - {name: big, kind: allocate, config: {value: 300}}\n"
        "  - {name: after, kind: allocate, config: {value: 0}}\n"
    )
    results = {r.name: r.peak_rss_mib for r in run_recipe(load_recipe(path))}
    assert results["big"] - results["small"] > 250  # the big stage raised the run's peak
    assert results["after"] >= results["big"]  # and the mark keeps it
    stages = json.loads((tmp_path / "run" / "run.json").read_text())["stages"]
    assert [s["peak_rss_mib"] for s in stages] == list(results.values())


def test_no_progress_reaches_lightning_without_changing_keys(
    recipe_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[dict[str, Any]] = []

    def record(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
        seen.append(dict(ctx.trainer))
        return _produce(ctx)

    monkeypatch.setitem(
        stage_registry.STAGES,
        "count",
        StageKind("count", "test", CountConfig, record, {"up": False}),
    )
    quiet = run_recipe(load_recipe(recipe_path), progress=False)
    assert [t.get("enable_progress_bar") for t in seen] == [False, False]
    again = run_recipe(load_recipe(recipe_path), progress=True)
    assert all(r.cached for r in again)  # same stage directories: progress is not in the key
    assert [r.directory for r in again] == [r.directory for r in quiet]


def _fill_disk(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    (ctx.directory / "small.txt").write_text("fits")
    atomic_write_npz(ctx.directory / "weights.npz", w=np.zeros(4))  # the disk fills here
    return {"weights": "weights.npz"}, {}


def _fill_disk_raw(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    # a write through another library's open file: the OSError carries no file name
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("run, file", [(_fill_disk, "weights.npz"), (_fill_disk_raw, None)])
def test_a_full_disk_names_the_stage_the_file_and_the_space_left(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    run: Any,
    file: str | None,
) -> None:
    from tactile_bench.cli import main

    monkeypatch.setitem(
        stage_registry.STAGES, "fill", StageKind("fill", "test", CountConfig, run, {})
    )

    def no_space(*args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a write() raises it

    monkeypatch.setattr(np, "savez", no_space)
    path = tmp_path / "r.yaml"
    path.write_text(f"name: r\nrun_dir: {tmp_path / 'run'}\nstages:\n  - {{name: a, kind: fill}}\n")
    assert main(["fit", str(path), "--no-progress"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    stage_dir = next((tmp_path / "run").glob("a-*"))
    written = stage_dir / file if file else stage_dir
    doing = "while writing it" if file else "while writing there"
    assert error.startswith(f"error: stage a: {written}: No space left on device {doing}; ")
    assert error.endswith(" free on the disk of " + str(written if written.exists() else stage_dir))
    # nothing half-written: no weights file, no temporary file, the stage not marked done
    assert sorted(p.name for p in stage_dir.iterdir()) == (["small.txt"] if file else [])


def test_a_fingerprint_sees_one_changed_pixel_past_its_first_chunk() -> None:
    """The moments are summed a chunk of 1 << 20 values at a time; the pixel is in the second."""
    x = torch.rand(300, 3, 64, 64)
    y = x.clone()
    y[123, 1, 7, 9] += 0.25
    assert fingerprint("c", x) == fingerprint("c", x.clone())
    assert fingerprint("c", x) != fingerprint("c", y)


def test_a_full_disk_in_a_command_names_the_command_and_its_output(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from tactile_bench.cli import main
    from tactile_bench.report import contact_sheet

    def no_space(*args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(contact_sheet, "render_contact_sheet", no_space)
    out = tmp_path / "sheet.png"
    assert main(["render", "--chars", "A", "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"error: render: {out}: No space left on device while writing there; ")
    assert error.endswith(f" free on the disk of {tmp_path}")
