"""``executor: ray``: each ready stage a task on a (here: local) Ray cluster; skipped without ray.

The recipe runs as a user runs it (``python -m tactile_bench fit ... --set executor=ray``);
its stage tasks are killed once the translator fit has a checkpoint, as a lost node would
lose them; Ray re-runs them, the fit resumes from its checkpoint, and the run dir is then
complete under one machine's cache keys.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tactile_bench.pipeline.recipe import RaySettings, Stage
from tactile_bench.pipeline.stages import STAGES

RECIPE = """
name: small_ray
seed: 0
trainer: {accelerator: cpu, enable_progress_bar: false, checkpoint_every_n_steps: 2}
stages:
  - name: braille
    kind: braille_data
    config: {chars: AB, n_finetune: 16, n_test: 8, n_classifier: 40, n_classifier_test: 16,
             image_size: 32}
  - name: fit
    kind: fit_translator
    inputs: {braille: braille}
    config:
      translator: diffusion
      eval_pairs: 4
      translator_config: {preset: tiny, image_size: 32, max_steps: 60, batch_size: 4}
  - name: classify_real
    kind: classify
    inputs: {data: braille}
    config: {row: real, train_images: real, train_set: finetune,
             classifier: {width: 4, epochs: 2, batch_size: 4}}
  - name: report
    kind: report
    inputs: {rows: [classify_real]}
"""
TIMEOUT_S = 600


def _stage(kind: str) -> Stage:
    return Stage(kind, STAGES[kind], STAGES[kind].config_model.model_construct(), {})


def test_a_stage_asks_ray_for_a_gpu_only_when_it_runs_networks_on_one() -> None:
    from tactile_bench.pipeline.ray_executor import stage_needs

    settings = RaySettings(cpus_per_stage=2)
    gpu = {"accelerator": "gpu"}
    assert stage_needs(_stage("fit_translator"), gpu, settings) == {"num_cpus": 2, "num_gpus": 1}
    assert stage_needs(_stage("braille_data"), gpu, settings) == {"num_cpus": 2, "num_gpus": 0}
    cpu = {"accelerator": "cpu"}
    assert stage_needs(_stage("fit_translator"), cpu, settings)["num_gpus"] == 0


def _stage_workers() -> list[int]:
    """Ray worker processes running a stage now (Ray titles them after the task)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if cmdline.startswith(b"ray::execute_stage"):
            pids.append(int(entry.name))
    return pids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds Ray's workers through /proc")
def test_ray_runs_the_stages_and_reruns_those_whose_worker_was_lost(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    recipe = tmp_path / "small.yaml"
    recipe.write_text(RECIPE)
    run_dir = tmp_path / "run"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    env.pop("RAY_ADDRESS", None)  # a local instance, never a cluster the machine may know
    base = [sys.executable, "-m", "tactile_bench", "fit", str(recipe), "--run-dir", str(run_dir)]
    base.append("--no-progress")
    with (tmp_path / "ray.log").open("w+") as log:
        driver = subprocess.Popen(
            [*base, "--set", "executor=ray"],
            cwd=tmp_path,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        deadline = time.monotonic() + TIMEOUT_S
        while not list(run_dir.glob("fit-*/checkpoints/last.ckpt")):
            assert driver.poll() is None, "the run ended before the fit's first checkpoint"
            assert time.monotonic() < deadline
            time.sleep(0.05)
        killed = _stage_workers()
        for pid in killed:  # what a lost node does to the tasks it ran
            os.kill(pid, signal.SIGKILL)
        code = driver.wait(timeout=TIMEOUT_S)
        log.seek(0)
        output = log.read()
    assert killed
    assert code == 0, output[-3000:]
    assert "sent to Ray (1 CPU)" in output
    assert "resuming from" in output  # the re-run fit went on from the lost one's checkpoint
    stages = {s["name"]: s for s in json.loads((run_dir / "run.json").read_text())["stages"]}
    assert not any(s["cached"] for s in stages.values())

    # one machine, no Ray, on the same run dir: every stage is found under its own key
    again = subprocess.run(base, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr[-3000:]
    stages = {s["name"]: s for s in json.loads((run_dir / "run.json").read_text())["stages"]}
    assert all(s["cached"] for s in stages.values())
