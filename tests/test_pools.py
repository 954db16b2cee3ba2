"""Worker pools end with their stage: no run hangs at exit (issue 39).

A corpus stage run side by side (``jobs: 2``) on more threads than one worker needs builds
its objects in a pool of its own, inside the side-by-side worker. Left open, that pool's
idle workers kept the side-by-side worker from exiting and the run never returned.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactile_bench.pools import close_kept_pools, kept_pool, spawned_pool

RECIPE = """\
name: pool_exit
seed: 0
jobs: 2
stages:
  - name: corpus
    kind: ycb_slide_data
    config: {n_pairs: 40, objects: [004_sugar_box, 055_baseball]}
"""


def test_side_by_side_corpus_stage_exits(tmp_path: Path) -> None:
    recipe = tmp_path / "pool_exit.yaml"
    recipe.write_text(RECIPE)
    env = {**os.environ, "TACTILE_BENCH_NO_WANDB": "1"}
    command = [sys.executable, "-m", "tactile_bench", "--threads", "4", "fit", str(recipe)]
    command += ["--run-dir", str(tmp_path / "run"), "--no-progress"]
    try:
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=240)
    except subprocess.TimeoutExpired as hung:
        pytest.fail(f"the run did not exit after its last stage: {hung.stderr!r}"[-2000:])
    assert done.returncode == 0, done.stderr[-2000:]
    assert "stage corpus: done" in done.stderr
    assert "leaked semaphore" not in done.stderr


def test_pool_stops_its_workers_when_the_block_ends() -> None:
    with spawned_pool(2) as pool:
        assert sorted(pool.map(abs, [-1, -2, 3])) == [1, 2, 3]
        processes = list(pool._processes.values())
    assert processes and not any(p.is_alive() for p in processes)


def test_pool_refuses_no_workers() -> None:
    with pytest.raises(ValueError, match="at least one worker"), spawned_pool(0):
        pass


def test_a_kept_pool_serves_later_stages_until_closed() -> None:
    first = kept_pool(1)
    pid = first.submit(os.getpid).result()
    assert kept_pool(1) is first and first.submit(os.getpid).result() == pid  # no new spawn
    workers = list(first._processes.values())
    close_kept_pools()
    assert workers and not any(p.is_alive() for p in workers)
    assert kept_pool(1) is not first  # a later run spawns anew
    close_kept_pools()


WORKER_KEEPS_A_POOL = """\
import os
from tactile_bench.pools import kept_pool, spawned_pool

def keep_one() -> int:
    return kept_pool(1).submit(os.getpid).result()

if __name__ == "__main__":
    with spawned_pool(1) as outer:
        print("inner worker", outer.submit(keep_one).result())
    print("outer pool joined")
"""


def test_a_worker_that_keeps_a_pool_still_exits(tmp_path: Path) -> None:
    """A side-by-side worker whose classify stage kept a seed pool: at its exit, the kept
    pool stops before multiprocessing joins the worker's children (else: a hang)."""
    script = tmp_path / "keeps.py"
    script.write_text(WORKER_KEEPS_A_POOL)
    try:
        done = subprocess.run(
            [sys.executable, str(script)], capture_output=True, text=True, timeout=120
        )
    except subprocess.TimeoutExpired as hung:
        pytest.fail(f"the worker did not exit with its kept pool: {hung.stderr!r}"[-2000:])
    assert done.returncode == 0, done.stderr[-2000:]
    assert "outer pool joined" in done.stdout
