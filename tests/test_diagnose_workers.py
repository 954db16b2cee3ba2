"""The diagnosis's fits side by side in worker processes (issue 47, ``diagnose.workers``).

The mapped functions are module-level: the spawned workers import this module by name, so
it imports the diagnosis itself only inside the tests that run it (seconds a worker).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.diagnose.breakdown import WAIT_WORKERS
from tactile_bench.diagnose.workers import auto_workers, fit_workers, map_fits, parse_workers
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.timing import SpanTimer, timed_span


class _Reference:
    """Stands in for ``scene.FitReference``: a cache of lookups by key."""

    def __init__(self) -> None:
        self.lookups: dict[str, Any] = {"known": 0}


def _pid_and(arg: int, delay: float = 0.0) -> tuple[int, int]:
    time.sleep(delay)
    return os.getpid(), arg


def _add_lookup(reference: _Reference, key: str) -> int:
    """A fit that caches a lookup in the reference it reads (as ``lookup_for`` does)."""
    assert "known" in reference.lookups  # the worker sees what the parent had cached
    reference.lookups[key] = f"table {key}"
    return len(key)


def _timed(arg: int) -> int:
    with timed_span("x"):
        time.sleep(0.01)
        return 2 * arg


@pytest.fixture(scope="class")
def two_workers() -> Iterator[None]:
    """Two spawned workers, shared by a class's tests (each start-up imports torch)."""
    with fit_workers(2):
        yield


def test_without_workers_the_calls_run_here_in_order() -> None:
    finished: list[int] = []
    out = map_fits(_pid_and, [(3,), (1,), (2,)], done=finished.append)
    assert out == [(os.getpid(), 3), (os.getpid(), 1), (os.getpid(), 2)]
    assert finished == [0, 1, 2]
    assert map_fits(_pid_and, []) == []


@pytest.mark.usefixtures("two_workers")
class TestInWorkers:
    def test_calls_run_in_the_workers_and_come_back_in_call_order(self) -> None:
        finished: list[int] = []
        # the first calls sleep longest: they finish after the later ones
        calls = [(0, 0.3), (1, 0.2), (2, 0.1), (3, 0.0)]
        out = map_fits(_pid_and, calls, done=finished.append)
        assert [arg for _, arg in out] == [0, 1, 2, 3]
        assert all(pid != os.getpid() for pid, _ in out)
        assert sorted(finished) == [0, 1, 2, 3]
        # a single call is not worth a worker
        assert map_fits(_pid_and, [(7,)]) == [(os.getpid(), 7)]

    def test_lookups_a_worker_fits_are_cached_here(self) -> None:
        reference = _Reference()
        calls = [(reference, key) for key in ("ab", "cde", "f")]
        assert map_fits(_add_lookup, calls, reference) == [2, 3, 1]
        assert reference.lookups == {
            "known": 0,
            "ab": "table ab",
            "cde": "table cde",
            "f": "table f",
        }

    def test_the_workers_spans_are_added_to_the_timer_here(self) -> None:
        with SpanTimer() as timer:
            assert map_fits(_timed, [(1,), (2,), (3,)]) == [2, 4, 6]
        assert timer.calls["x"] == 3
        assert timer.wall["x"] >= 0.03 and timer.inclusive["x"] >= 0.03
        assert timer.calls[WAIT_WORKERS] == 1 and timer.wall[WAIT_WORKERS] > 0


def test_parse_workers() -> None:
    assert parse_workers("auto") == auto_workers() >= 1
    assert parse_workers(None) == auto_workers()
    assert parse_workers("3") == 3 and parse_workers(1) == 1
    for bad in ("0", "x", "-1", "2.5", "", "65", "100000"):
        with pytest.raises(TactileBenchError, match="--workers") as err:
            parse_workers(bad)
        assert "\n" not in str(err.value) and repr(bad) in str(err.value)


def test_diagnose_refuses_no_workers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tactile_bench.cli import main
    from tactile_bench.diagnose.paired import write_paired
    from tests.test_diagnose_paired import tiny_pairs

    root = write_paired(tmp_path / "pairs", tiny_pairs(n=6))
    out = tmp_path / "out"
    args = ["diagnose", str(root), "--out", str(out), "--no-progress", "--workers", "0"]
    assert main(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--workers" in lines[0]
    assert not out.exists()


def _answer(result: Any) -> dict[str, Any]:
    """What a diagnosis names: the selected effects in order and every fit's parameters."""
    return {
        "selected": [row.effect for row in result.ranking],
        "params": {row.effect: row.params for row in result.ranking},
        "singles": {row.effect: row.params for row in result.singles},
        "stability": result.stability.named_first if result.stability else None,
    }


def _same_params(a: dict[str, float], b: dict[str, float]) -> bool:
    return a.keys() == b.keys() and all(
        b[k] == pytest.approx(v, rel=1e-3, abs=1e-6) for k, v in a.items()
    )


@pytest.mark.slow  # ~25 s on 2 busy cores: the workers' start-up and imports
def test_explain_gap_gives_the_same_answer_in_workers() -> None:
    from tactile_bench.diagnose.validate import planted_pairs
    from tactile_bench.diagnose.which import explain_gap
    from tactile_bench.effects import EFFECTS
    from tactile_bench.geometry.braille import BrailleSpec
    from tactile_bench.sensor.heightfield import build_bank

    bank = build_bank(("A", "L", "#"), BrailleSpec())
    planted = {"vignetting": {"corner_loss": 0.5}, "gamma_white_balance": {"gamma": 1.5}}
    data = planted_pairs(
        bank, {k: {**EFFECTS[k].neutral_params(), **v} for k, v in planted.items()}, 12, 3, 32
    )
    idx = torch.arange(len(data))
    names = ["vignetting", "gamma_white_balance", "led_diffusivity"]
    here = _answer(explain_gap(data, idx[::2], idx[1::2], names, progress=False))
    with fit_workers(2), SpanTimer() as timer:
        there = _answer(explain_gap(data, idx[::2], idx[1::2], names, progress=False))
    assert timer.calls[WAIT_WORKERS] >= 2  # the fits did run in the workers
    assert here["selected"] == there["selected"] and len(here["selected"]) >= 2
    assert here["stability"] == there["stability"]
    for key in ("params", "singles"):
        assert here[key].keys() == there[key].keys()
        for effect, params in here[key].items():
            assert _same_params(params, there[key][effect]), (key, effect)
