"""The pieces of a launch over several processes, in one process: the run-dir lock that
holds across machines, the trainer settings a launcher decides, the sampler's shares."""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

import pytest
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline import run_lock
from tactile_bench.pipeline.launch import (
    Launch,
    completed_trainer,
    finish,
    launched_externally,
)
from tactile_bench.pipeline.run_lock import RunDirLock, check_claim, owner_path, read_owner
from tactile_bench.training import ResumableSampler, processes


def _claim(run_dir: Path, host: str, age_s: float, pid: int = 4242) -> Path:
    path = owner_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"host": host, "pid": pid, "launch": "abc123", "since": 0}))
    then = time.time() - age_s
    os.utime(path, (then, then))
    return path


def test_the_lock_names_host_pid_and_launch_and_goes_with_the_run(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    with RunDirLock(run_dir, "launch1"):
        claim = read_owner(owner_path(run_dir))
        assert claim is not None
        assert (claim["host"], claim["pid"], claim["launch"]) == (
            socket.gethostname(),
            os.getpid(),
            "launch1",
        )
        assert check_claim(run_dir, "launch1") is None  # the ranks of this launch get in
        assert "launch1" in str(check_claim(run_dir, "other"))
    assert not owner_path(run_dir).exists()


def test_a_live_claim_from_another_machine_refuses_the_run(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    _claim(run_dir, "node-b", age_s=5)
    with pytest.raises(TactileBenchError, match="process 4242 on node-b .*launch abc123"):
        RunDirLock(run_dir, "launch2").acquire()
    assert read_owner(owner_path(run_dir))["host"] == "node-b"  # left as it was
    # and the flock taken on the way is released: this host can still try again
    _claim(run_dir, "node-b", age_s=run_lock.STALE_S + 60)
    with RunDirLock(run_dir, "launch2"):
        assert read_owner(owner_path(run_dir))["launch"] == "launch2"


def test_a_dead_claim_of_this_machine_is_taken_over_at_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    run_dir = tmp_path / "run"
    _claim(run_dir, socket.gethostname(), age_s=1)
    with RunDirLock(run_dir, "launch3"):
        assert read_owner(owner_path(run_dir))["launch"] == "launch3"
    assert "taking over the claim of process 4242" in caplog.text


def test_the_holder_keeps_its_claim_fresh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(run_lock, "HEARTBEAT_S", 0.05)
    run_dir = tmp_path / "run"
    with RunDirLock(run_dir, "launch4"):
        path = owner_path(run_dir)
        os.utime(path, (0, 0))
        deadline = time.monotonic() + 10
        while path.stat().st_mtime == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert path.stat().st_mtime > time.time() - 60


def test_the_launcher_decides_devices_and_nodes_and_a_contradiction_is_one_line() -> None:
    settings = completed_trainer({"accelerator": "cpu"}, world=4, per_node=2)
    assert (settings["strategy"], settings["devices"], settings["num_nodes"]) == ("ddp", 2, 2)
    assert processes(settings) == 4
    with pytest.raises(TactileBenchError, match="trainer.devices: 1, but the launcher started 4"):
        completed_trainer({"devices": 1}, world=4, per_node=2)
    with pytest.raises(TactileBenchError, match="trainer.strategy: 'ddp_spawn'"):
        completed_trainer({"strategy": "ddp_spawn"}, world=2, per_node=2)


def test_the_environment_of_each_launcher_is_read(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in list(os.environ):
        if name.startswith(("SLURM_", "TORCHELASTIC_")) or name in (
            "RANK",
            "LOCAL_RANK",
            "WORLD_SIZE",
            "GROUP_RANK",
            "LOCAL_WORLD_SIZE",
        ):
            monkeypatch.delenv(name)
    assert launched_externally() is None
    torchrun = {"TORCHELASTIC_RUN_ID": "x", "RANK": "3", "LOCAL_RANK": "1", "LOCAL_WORLD_SIZE": "2"}
    for name, value in {**torchrun, "WORLD_SIZE": "4"}.items():
        monkeypatch.setenv(name, value)
    assert launched_externally() == ("torchrun", 4, 2)
    for name in torchrun:
        monkeypatch.delenv(name)
    slurm = {"SLURM_NTASKS": "8", "SLURM_JOB_NUM_NODES": "2", "SLURM_JOB_NAME": "table1"}
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    assert launched_externally() == ("slurm", 8, 4)


def test_the_sampler_shares_one_permutation_between_processes_and_resumes_in_each() -> None:
    def sampler(rank: int) -> ResumableSampler:
        s = ResumableSampler(10, torch.Generator().manual_seed(0), batch_size=2)
        s.shard = (3, rank)
        return s

    alone = list(ResumableSampler(10, torch.Generator().manual_seed(0), 2))
    shares = [list(sampler(rank)) for rank in range(3)]
    assert [len(s) for s in shares] == [4, 4, 4]  # 10 padded to 12, as DistributedSampler
    assert sorted(i for s in shares for i in s) == sorted(alone + alone[:2])
    # resumed after one batch of its own, each process goes on with its next batch
    resumed = sampler(1)
    first = sampler(1)
    state = first.generator.get_state()
    resumed.resume(state, batches_done=1)
    assert list(resumed) == shares[1][2:]


def test_a_finished_launch_destroys_its_process_groups(tmp_path: Path) -> None:
    """Lightning destroys its group at exit for NCCL only; a gloo group left to the
    interpreter's finalisation aborted a finished rank (issue 48). ``finish`` destroys them
    while the process is whole, after every rank has arrived."""
    import torch.distributed as dist

    store = dist.FileStore(str(tmp_path / "store"), 1)
    dist.init_process_group("gloo", store=store, rank=0, world_size=1)
    try:
        follower = Launch(2, 1, "torchrun", "test", dist.new_group(backend="gloo"))
        finish(follower)
        assert not dist.is_initialized()
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()
