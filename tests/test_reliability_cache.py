"""Nothing half-written, nothing corrupt reused: truncated outputs and manifests are rebuilt."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.io import atomic_torch_save, atomic_write_npz, atomic_write_text, file_sha256
from tactile_bench.pipeline import stages as stage_registry
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.pipeline.runner import DONE, run_recipe, stage_key
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind

CALLS: list[str] = []


class ArraysConfig(StageConfig):
    value: float = 1.0
    fail: bool = False


def _produce(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    """Writes an .npz and a .pt as the real stages do (atomically), from its input if any."""
    CALLS.append(ctx.name)
    if ctx.config.fail:
        raise TactileBenchError("data/x.png: not a readable image")
    base = sum(float(np.load(r.path("arrays"))["x"].sum()) for r in ctx.inputs.get("up", []))
    x = np.full(1000, ctx.config.value + base / 1000)
    atomic_write_npz(ctx.directory / "arrays.npz", x=x)
    atomic_torch_save({"w": torch.from_numpy(x)}, ctx.directory / "model.pt")
    return {"arrays": "arrays.npz", "model": "model.pt"}, {"sum": float(x.sum())}


@pytest.fixture
def recipe(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setitem(
        stage_registry.STAGES,
        "arrays",
        StageKind("arrays", "test stage", ArraysConfig, _produce, {"up": False}),
    )
    CALLS.clear()
    path = tmp_path / "r.yaml"
    path.write_text(
        f"name: r\nrun_dir: {tmp_path / 'run'}\nstages:\n"
        "  - {name: a, kind: arrays, config: {value: 2}}\n"
        "  - {name: b, kind: arrays, inputs: {up: a}}\n"
    )
    return path


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda d: _truncate(d / "arrays.npz"), "arrays is missing or corrupted"),
        (lambda d: _truncate(d / "model.pt"), "model is missing or corrupted"),
        (lambda d: (d / "model.pt").unlink(), "model is missing or corrupted"),
        (lambda d: (d / DONE).write_text('{"outputs": {"arr'), "unreadable manifest"),
        (lambda d: (d / DONE).write_text('{"name": "a"}'), "unreadable manifest"),
        (lambda d: (d / DONE).write_bytes(b"\x00\xff" * 50), "unreadable manifest"),
    ],
    ids=["truncated npz", "truncated pt", "missing pt", "cut manifest", "manifest keys", "binary"],
)
def test_corrupted_cache_entry_is_detected_and_rebuilt(
    recipe: Path, damage: Any, message: str, caplog: pytest.LogCaptureFixture
) -> None:
    first = run_recipe(load_recipe(recipe), progress=False)
    hashes = {name: file_sha256(first[0].path(name)) for name in ("arrays", "model")}
    damage(first[0].directory)
    with caplog.at_level(logging.WARNING, logger="tactile_bench"):
        second = run_recipe(load_recipe(recipe), progress=False)
    assert message in caplog.text
    assert CALLS == ["a", "b", "a"]  # a rebuilt; b reused: a's content came back identical
    assert not second[0].cached and second[1].cached
    assert {name: file_sha256(second[0].path(name)) for name in hashes} == hashes


def test_a_failing_stage_names_itself_and_is_not_marked_done(recipe: Path, tmp_path: Path) -> None:
    run_recipe(load_recipe(recipe), progress=False)
    with pytest.raises(TactileBenchError, match=r"^stage b: data/x.png: not a readable image$"):
        run_recipe(load_recipe(recipe, ["b.fail=true"]), progress=False)
    (failed,) = [d for d in (tmp_path / "run").glob("b-*") if not (d / DONE).exists()]
    assert failed.is_dir()


def test_torch_save_is_byte_reproducible(tmp_path: Path) -> None:
    """torch names the archive after the (random) temporary file; ours must not vary."""
    state = {"w": torch.arange(5.0)}
    a = atomic_torch_save(state, tmp_path / "a.pt")
    b = atomic_torch_save(state, tmp_path / "sub" / "b.pt")
    assert file_sha256(a) == file_sha256(b)
    assert torch.equal(torch.load(a, weights_only=True)["w"], state["w"])


def test_a_failed_write_leaves_the_old_file_and_no_debris(tmp_path: Path) -> None:
    target = atomic_write_text(tmp_path / "results.md", "old\n")

    class Boom:
        def __reduce__(self) -> Any:
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_torch_save({"x": Boom()}, tmp_path / "results.md")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.md"]


def test_run_json_lists_each_stage_output_hash(recipe: Path, tmp_path: Path) -> None:
    results = run_recipe(load_recipe(recipe), progress=False)
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    for stage, result in zip(run["stages"], results, strict=True):
        assert stage["outputs"]["model"]["sha256"] == file_sha256(result.path("model"))


def test_display_and_checkpoint_settings_keep_the_cache_key(recipe: Path) -> None:
    """Changing how often a killed stage checkpoints must not orphan its checkpoint."""
    plain = load_recipe(recipe)
    tuned = load_recipe(
        recipe, ["trainer.checkpoint_every_n_steps=5", "trainer.enable_progress_bar=false"]
    )
    other = load_recipe(recipe, ["trainer.max_epochs=3"])
    keys = [stage_key(r, r.stages[0], {}) for r in (plain, tuned, other)]
    assert keys[0] == keys[1] != keys[2]
