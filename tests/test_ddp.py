"""Scale-out: a recipe's trainer settings reach Lightning, so a translator fits under DDP.

Two CPU processes with the gloo backend (``ddp_spawn``): the same code path a GPU node or
a multi-node run takes with ``strategy: ddp``.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from tactile_bench.cli import main

RECIPE = """
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


def test_translator_fit_runs_under_ddp_with_two_cpu_processes(tmp_path: Path) -> None:
    recipe = tmp_path / "ddp.yaml"
    recipe.write_text(RECIPE)
    run_dir = tmp_path / "run"
    assert main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"]) == 0
    stages = {s["name"]: s for s in json.loads((run_dir / "run.json").read_text())["stages"]}
    fit_dir = run_dir / stages["fit"]["directory"]
    payload = torch.load(fit_dir / "translator.pt", map_location="cpu", weights_only=False)
    assert payload["translator"] == "diffusion"
    # the two processes trained: the Lightning checkpoint records the steps they took
    ckpt = torch.load(fit_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 3
