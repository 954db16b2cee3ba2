"""Scale-out: a recipe under Lightning's DDP, torchrun and a two-node launch, on the CPU (gloo).

The launched tests run the command line as a user would (``python -m tactile_bench fit``,
``torchrun ... -m tactile_bench fit``), two processes each, on a small recipe with a
translator fit and a classifier stage; one launch of each kind, shared by the tests that
read it (module fixtures). ``ddp_spawn`` still runs in-process (its processes start inside
each fit).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from tactile_bench.cli import main

SPAWN_RECIPE = """
name: ddp
trainer: {accelerator: cpu, devices: 2, strategy: ddp_spawn, enable_progress_bar: false}
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 16, n_test: 8, n_classifier: 8, n_classifier_test: 8,
             image_size: 32}
  - name: fit
    kind: fit_translator
    inputs: {braille: braille}
    config:
      translator: diffusion
      fraction: 1.0
      translator_config: {preset: tiny, image_size: 32, max_steps: 3, batch_size: 4}
"""

#: enough steps that a kill lands inside the fit (checkpoints every 2 steps)
MAX_STEPS = 60
RECIPE = f"""
name: small_ddp
seed: 0
trainer: {{accelerator: cpu, enable_progress_bar: false, checkpoint_every_n_steps: 2}}
stages:
  - name: braille
    kind: braille_data
    config: {{chars: AB, n_finetune: 16, n_test: 8, n_classifier: 40, n_classifier_test: 16,
             image_size: 32}}
  - name: fit
    kind: fit_translator
    inputs: {{braille: braille}}
    config:
      translator: diffusion
      eval_pairs: 4
      translator_config: {{preset: tiny, image_size: 32, max_steps: {MAX_STEPS}, batch_size: 4}}
  - name: classify_real
    kind: classify
    inputs: {{data: braille}}
    config: {{row: real, train_images: real, train_set: finetune, parallel_seeds: 2,
              seeds: [0, 1], classifier: {{width: 4, epochs: 2, batch_size: 4}}}}
  - name: report
    kind: report
    inputs: {{rows: [classify_real]}}
"""
TIMEOUT_S = 600


def test_translator_fit_runs_under_ddp_spawn_with_two_cpu_processes(tmp_path: Path) -> None:
    recipe = tmp_path / "ddp.yaml"
    recipe.write_text(SPAWN_RECIPE)
    run_dir = tmp_path / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    stages = {s["name"]: s for s in json.loads((run_dir / "run.json").read_text())["stages"]}
    fit_dir = run_dir / stages["fit"]["directory"]
    payload = torch.load(fit_dir / "translator.pt", map_location="cpu", weights_only=False)
    assert payload["translator"] == "diffusion"
    # the two processes trained: the Lightning checkpoint records the steps they took
    ckpt = torch.load(fit_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 3


# ------------------------------------------------------------------ launched (subprocesses)
def _env() -> dict[str, str]:
    env = dict(os.environ)
    # one thread a process under every launcher (torchrun sets it, Lightning's launcher
    # would split the cores): the same float sums, so launches can be compared exactly
    env["OMP_NUM_THREADS"] = "1"
    for name in ("LOCAL_RANK", "RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT", "NODE_RANK"):
        env.pop(name, None)
    env.setdefault("WANDB_MODE", "offline")
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _fit_args(recipe: Path, run_dir: Path) -> list[str]:
    return ["-m", "tactile_bench", "fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]


def _torchrun(*args: str) -> list[str]:
    return [sys.executable, "-m", "torch.distributed.run", *args]


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        cmd, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=TIMEOUT_S
    )


def _stages(run_dir: Path) -> dict[str, dict]:
    return {s["name"]: s for s in json.loads((run_dir / "run.json").read_text())["stages"]}


def _weights(run_dir: Path) -> dict[str, torch.Tensor]:
    fit_dir = run_dir / _stages(run_dir)["fit"]["directory"]
    return torch.load(fit_dir / "translator.pt", map_location="cpu", weights_only=False)[
        "state_dict"
    ]


def _rows(run_dir: Path) -> list[dict]:
    return json.loads((run_dir / "results.json").read_text())["rows"]


@pytest.fixture(scope="module")
def launches(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The recipe, written once for every launch of this module."""
    folder = tmp_path_factory.mktemp("launches")
    (folder / "small.yaml").write_text(RECIPE)
    return folder


@pytest.fixture(scope="module")
def lightning_ddp(launches: Path) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """``python -m tactile_bench fit`` with ``strategy: ddp`` on two devices: Lightning's
    launcher re-runs the command for rank 1."""
    run_dir = launches / "lightning"
    cmd = [sys.executable, *_fit_args(launches / "small.yaml", run_dir)]
    cmd += ["--set", "trainer.strategy=ddp", "--set", "trainer.devices=2"]
    return run_dir, _run(cmd, launches)


def test_a_recipe_runs_under_lightning_ddp_and_rank_zero_writes_it(
    lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]],
) -> None:
    run_dir, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2 processes (lightning), this is rank 0" in proc.stderr
    # one table, printed by rank 0 only
    assert proc.stdout.count("run directory:") == 1
    stages = _stages(run_dir)
    assert [stages[n]["cached"] for n in stages] == [False] * 4
    # the fits trained on both processes, and said so in run.json and the table
    assert stages["fit"]["processes"] == stages["classify_real"]["processes"] == 2
    assert stages["braille"]["processes"] == stages["report"]["processes"] == 1
    assert "trained on 2 processes (DDP)" in (run_dir / "results.md").read_text()
    ckpt = torch.load(
        run_dir / stages["fit"]["directory"] / "checkpoints" / "last.ckpt",
        map_location="cpu",
        weights_only=False,
    )
    assert ckpt["global_step"] == MAX_STEPS
    # nothing from the follower's scratch folders nor a lock is left behind
    assert not list(run_dir.parent.glob(f".{run_dir.name}.tactile_bench.*"))
    assert not list(run_dir.rglob("*.tmp"))


#: Lightning notices a launch must not print (issue 48): an interval longer than the epoch a
#: process sees, and an epoch-level value logged unsynchronised
NOTICES = ("smaller than the logging interval", "sync_dist=True")


def test_a_launch_prints_no_lightning_notice_on_any_rank(
    lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]],
) -> None:
    """Both ranks write to this stderr (Lightning's launcher re-runs the command)."""
    _, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert not [line for line in proc.stderr.splitlines() if any(n in line for n in NOTICES)]


def test_parallel_seeds_are_one_at_a_time_under_a_launch(
    lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]],
) -> None:
    run_dir, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "parallel_seeds 2 -> 1 under a launch" in proc.stderr
    assert len(_rows(run_dir)) == 1


def test_only_training_stages_change_their_cache_key_under_ddp(
    lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]], launches: Path
) -> None:
    """The data stage's key is one process's; the fit's records the processes."""
    from tactile_bench.pipeline.recipe import load_recipe
    from tactile_bench.pipeline.runner import stage_key

    run_dir, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    stages = _stages(run_dir)
    one = load_recipe(launches / "small.yaml", [])
    assert stages["braille"]["directory"] == f"braille-{stage_key(one, one.stage('braille'), {})}"
    ddp = load_recipe(launches / "small.yaml", ["trainer.strategy=ddp", "trainer.devices=2"])
    braille = ddp.stage("braille")
    assert stage_key(one, braille, {}) == stage_key(ddp, braille, {})
    fit = one.stage("fit")
    assert stage_key(one, fit, {}) != stage_key(ddp, fit, {})


def _kill_rank_one_during_the_fit(cmd: list[str], run_dir: Path, cwd: Path) -> tuple[int, str]:
    """Start ``cmd`` (torchrun), SIGKILL its rank 1 once the fit has saved a checkpoint;
    returns torchrun's exit code and its output."""
    with (cwd / "killed.log").open("w+") as log:
        agent = subprocess.Popen(cmd, cwd=cwd, env=_env(), stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + TIMEOUT_S
        while not list(run_dir.glob("fit-*/checkpoints/last.ckpt")):
            assert agent.poll() is None, "the launch ended before the fit's first checkpoint"
            assert time.monotonic() < deadline
            time.sleep(0.05)
        workers = Path(f"/proc/{agent.pid}/task/{agent.pid}/children").read_text().split()
        killed = 0
        for pid in workers:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            if b"LOCAL_RANK=1" in environ:
                os.kill(int(pid), signal.SIGKILL)
                killed += 1
        assert killed == 1
        code = agent.wait(timeout=TIMEOUT_S)
        log.seek(0)
        return code, log.read()


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="finds ranks through /proc")
def test_torchrun_a_killed_rank_ends_the_launch_and_the_next_resumes_to_the_same_weights(
    launches: Path, lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]]
) -> None:
    """``torchrun --standalone --nproc_per_node 2``: SIGKILL rank 1 inside the fit; rank 0
    ends with one line and no finished fit; the same launch again resumes from the
    checkpoint and ends with the weights and table of the uninterrupted Lightning launch
    (same processes, same cache keys)."""
    run_dir = launches / "torchrun"
    cmd = _torchrun("--standalone", "--nproc_per_node", "2")
    cmd += _fit_args(launches / "small.yaml", run_dir)
    code, output = _kill_rank_one_during_the_fit(cmd, run_dir, launches)
    assert code != 0
    errors = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "rerun the same launch to resume" in errors[0], output[-3000:]
    (fit_dir,) = run_dir.glob("fit-*")
    assert not (fit_dir / "_done.json").exists()  # nothing half-written or claimed finished
    assert not list(run_dir.rglob("*.tmp"))

    again = _run(cmd, launches)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "resuming from" in again.stderr
    assert not [line for line in again.stderr.splitlines() if any(n in line for n in NOTICES)]
    reference, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _stages(run_dir)["fit"]["directory"] == _stages(reference)["fit"]["directory"]
    ours, theirs = _weights(run_dir), _weights(reference)
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)
    assert _rows(run_dir) == _rows(reference)


def test_two_nodes_sharing_one_rendezvous_run_the_recipe_once(
    launches: Path, lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]]
) -> None:
    """Two ``torchrun --nnodes 2`` (one process each) on this machine, one c10d rendezvous:
    one run dir, one table, the same cache keys as two processes on one node."""
    run_dir = launches / "two_nodes"
    port = _free_port()
    cmd = _torchrun(
        "--nnodes",
        "2",
        "--nproc_per_node",
        "1",
        "--rdzv_backend",
        "c10d",
        "--rdzv_endpoint",
        f"127.0.0.1:{port}",
        "--rdzv_id",
        "two-nodes",
    )
    cmd += _fit_args(launches / "small.yaml", run_dir)
    nodes = [
        subprocess.Popen(cmd, cwd=launches, env=_env(), stdout=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    outputs = [node.communicate(timeout=TIMEOUT_S)[0] for node in nodes]
    assert [node.returncode for node in nodes] == [0, 0]
    assert sum(out.count("run directory:") for out in outputs) == 1
    reference, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    ours, theirs = _stages(run_dir), _stages(reference)
    assert {n: s["directory"] for n, s in ours.items() if n != "report"} == {
        n: s["directory"] for n, s in theirs.items() if n != "report"
    }
    assert ours["fit"]["processes"] == 2


@pytest.mark.slow
def test_srun_two_tasks_run_the_recipe_as_slurm_would_start_them(
    launches: Path, lightning_ddp: tuple[Path, subprocess.CompletedProcess[str]]
) -> None:
    """Two processes with the variables ``srun --ntasks-per-node 2`` gives its tasks (what
    docs/scaling.md's sbatch file runs): Lightning's SLURMEnvironment reads the ranks."""
    run_dir = launches / "srun"
    job = {
        "SLURM_JOB_ID": "4242",
        "SLURM_JOB_NAME": "tactile_bench",
        "SLURM_NTASKS": "2",
        "SLURM_NTASKS_PER_NODE": "2",
        "SLURM_JOB_NUM_NODES": "1",
        "SLURM_NODEID": "0",
        "SLURM_NODELIST": "127.0.0.1",
        "MASTER_PORT": str(_free_port()),
    }
    cmd = [sys.executable, *_fit_args(launches / "small.yaml", run_dir)]
    tasks = [
        subprocess.Popen(
            cmd,
            cwd=launches,
            env={**_env(), **job, "SLURM_PROCID": str(r), "SLURM_LOCALID": str(r)},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for r in range(2)
    ]
    outputs = [task.communicate(timeout=TIMEOUT_S) for task in tasks]
    assert [task.returncode for task in tasks] == [0, 0], outputs[0][1][-3000:]
    assert "2 processes (slurm), this is rank 0" in outputs[0][1]
    reference, proc = lightning_ddp
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _stages(run_dir)["fit"]["directory"] == _stages(reference)["fit"]["directory"]
    assert _rows(run_dir) == _rows(reference)


#: launches of the repeat test: the abort at exit came in about 1 launch in 11 (issue 48)
REPEATS = 20


@pytest.mark.slow
def test_every_torchrun_launch_of_a_finished_recipe_exits_zero(launches: Path) -> None:
    """A finished launch once aborted at exit on rank 1 (``terminate called without an
    active exception``: gloo groups left to the interpreter's finalisation), and torchrun
    reported it failed. Each launch here retrains the classifier on both ranks."""
    cmd = _torchrun("--standalone", "--nproc_per_node", "2")
    cmd += _fit_args(launches / "small.yaml", launches / "repeat")
    cmd += ["--set", f"fit.translator_config.max_steps={4}", "--force", "classify_real"]
    failed = []
    for attempt in range(REPEATS):
        proc = _run(cmd, launches)
        if proc.returncode != 0 or "terminate called" in proc.stderr:
            failed.append((attempt, proc.returncode, proc.stderr[-800:]))
    assert not failed, f"{len(failed)} of {REPEATS} launches failed; first: {failed[0]}"
