"""``jobs: N``: stages that do not read each other overlap, and nothing else changes.

The stages here sleep instead of computing, so the overlap shows in their start and end
times however busy the machine is; they run in spawned workers, which import this module.
"""

from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import time
import weakref
from pathlib import Path
from typing import Any

import pytest

from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline import stages as stage_registry
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.pipeline.runner import DONE, run_recipe
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.pools import spawned_pool

REPO = Path(__file__).resolve().parents[1]


class NapConfig(StageConfig):
    seconds: float = 0.0
    fail: bool = False
    seed_pool: bool = False  # start a pool of workers inside the stage, as classify does
    meet: str = ""  # wait (at most a minute) until this stage has started too


def _nap(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    """Sleeps, then writes when it ran and which process ran it."""
    start = time.time()
    (ctx.run_dir / f"{ctx.name}.started").touch()
    if ctx.config.fail:
        raise TactileBenchError("planted failure")
    other = ctx.run_dir / f"{ctx.config.meet}.started"
    while ctx.config.meet and not other.exists():
        if time.time() > start + 60:
            raise TactileBenchError(f"{ctx.config.meet} did not start while {ctx.name} ran")
        time.sleep(0.05)
    time.sleep(ctx.config.seconds)
    if ctx.config.seed_pool:
        with spawned_pool(2) as pool:
            assert pool.submit(abs, -3).result() == 3
    record = {"start": start, "end": time.time(), "pid": os.getpid()}
    (ctx.directory / "times.json").write_text(json.dumps(record))
    return {"times": "times.json"}, record


NAP = StageKind("nap", "test stage", NapConfig, _nap, {"up": False})
SUMMARY = StageKind("nap_summary", "test stage", NapConfig, _nap, {}, waits_for_earlier=True)


def register(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(stage_registry.STAGES, "nap", NAP)
    monkeypatch.setitem(stage_registry.STAGES, "nap_summary", SUMMARY)


def write_recipe(
    tmp_path: Path, jobs: int, a: str = "{seconds: 1.5}", b: str = "{seconds: 1.5}"
) -> Path:
    """a and b read nothing; c reads a; d summarises the run (reads every earlier stage)."""
    path = tmp_path / "r.yaml"
    path.write_text(
        f"name: r\nrun_dir: {tmp_path / 'run'}\njobs: {jobs}\nstages:\n"
        f"  - {{name: a, kind: nap, config: {a}}}\n"
        f"  - {{name: b, kind: nap, config: {b}}}\n"
        "  - {name: c, kind: nap, inputs: {up: a}, config: {seconds: 0.1}}\n"
        "  - {name: d, kind: nap_summary, config: {seconds: 0.0}}\n"
    )
    return path


def overlap(x: dict[str, float], y: dict[str, float]) -> bool:
    return x["start"] < y["end"] and y["start"] < x["end"]


def test_independent_stages_overlap_and_dependents_wait(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    register(monkeypatch)
    # each waits for the other to start: they can only both finish side by side
    meet = write_recipe(tmp_path, 2, a="{seconds: 0.5, meet: b}", b="{seconds: 0.5, meet: a}")
    side = run_recipe(load_recipe(meet))
    a, b, c, d = (r.metrics for r in side)
    assert overlap(a, b)  # neither reads the other
    assert a["pid"] != b["pid"] and os.getpid() not in {a["pid"], b["pid"]}
    assert c["start"] >= a["end"]  # c reads a
    assert d["start"] >= max(a["end"], b["end"], c["end"])  # d reads every earlier stage
    # the same cache entries as one at a time: a rerun with one job finds every stage
    again = run_recipe(load_recipe(meet, ["jobs=1"]))
    assert [r.directory for r in again] == [r.directory for r in side]
    assert all(r.cached for r in again)
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert [s["name"] for s in record["stages"]] == ["a", "b", "c", "d"]


def test_one_job_runs_in_turn_here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    register(monkeypatch)
    results = {r.name: r.metrics for r in run_recipe(load_recipe(write_recipe(tmp_path, 1)))}
    assert not overlap(results["a"], results["b"])
    assert {m["pid"] for m in results.values()} == {os.getpid()}


def test_a_failing_stage_stops_the_run_with_its_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    register(monkeypatch)
    recipe = load_recipe(write_recipe(tmp_path, 2, a="{fail: true}"))
    with pytest.raises(TactileBenchError, match=r"^stage a: planted failure$"):
        run_recipe(recipe)
    assert not list((tmp_path / "run").glob(f"a-*/{DONE}"))
    assert not list((tmp_path / "run").glob("c-*"))  # never started: its input failed


_LEFT: list[weakref.ref] = []  # what each _leave_a_cycle left behind


class _Held:
    """Stands for a trainer or model that a stage leaves in a reference cycle."""


def _leave_a_cycle(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    held = _Held()
    held.self = held
    _LEFT.append(weakref.ref(held))
    (ctx.directory / "out.txt").write_text("x")
    return {"out": "out.txt"}, {}


def test_a_stage_leaves_no_cycle_alive_for_the_next(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Cycles wait for a full collection; table1's classifier stages kept ~1.4 GB each so."""
    kind = StageKind("cycle", "test stage", NapConfig, _leave_a_cycle, {})
    monkeypatch.setitem(stage_registry.STAGES, "cycle", kind)
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        f"name: r\nrun_dir: {tmp_path / 'run'}\nstages:\n  - {{name: a, kind: cycle}}\n"
    )
    gc.disable()  # only the runner's own collection may free it
    try:
        run_recipe(load_recipe(recipe))
        assert _LEFT and _LEFT[-1]() is None
    finally:
        gc.enable()


#: a fresh interpreter with the test stage kinds registered, ready to call ``main``
REGISTERED = """
import sys
from tactile_bench.cli import main
from tactile_bench.pipeline import stages
from tests.test_side_by_side import NAP, SUMMARY
stages.STAGES["nap"] = NAP
stages.STAGES["nap_summary"] = SUMMARY
"""


def test_a_worker_with_a_pool_of_its_own_exits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A classify stage in a worker keeps its seed workers for the next stage; when the run
    ends they must stop too, or the worker (and the runner waiting for it) never exits."""
    register(monkeypatch)
    recipe = write_recipe(tmp_path, 2, a="{seed_pool: true}")
    script = REGISTERED + "sys.exit(main(['fit', sys.argv[1], '--no-progress']))\n"
    done = subprocess.run(
        [sys.executable, "-c", script, str(recipe)], cwd=REPO, timeout=120, capture_output=True
    )
    assert done.returncode == 0, done.stderr.decode()[-2000:]


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_sigterm_stops_the_workers_and_exits_130(tmp_path: Path) -> None:
    recipe = write_recipe(tmp_path, 2, a="{seconds: 120}")
    proc = subprocess.Popen(
        [sys.executable, "-c", REGISTERED + "sys.exit(main(['fit', sys.argv[1]]))", str(recipe)],
        cwd=REPO,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 60
    while not list((tmp_path / "run").glob("b-*")) and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(3)  # the workers have started their stages
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert not list((tmp_path / "run").glob(f"a-*/{DONE}"))
    children = subprocess.run(
        ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
    ).stdout.split()
    assert children == []
