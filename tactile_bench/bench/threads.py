"""Threads and OpenMP wait policy: the default sampler in fresh processes, side by side.

torch's CPU kernels run on OpenMP. GNU OpenMP's default wait policy lets an idle worker
thread spin for a while before sleeping; on a laptop whose other core is busy that
spinning competes with the work itself, and two threads can run SLOWER than one. The
policy is read once, when the OpenMP runtime loads with torch, so each setting is measured
in its own subprocess (same checkpoint, same contacts, same sampler): 1 thread, 2 threads
with the active policy, 2 threads with ``OMP_WAIT_POLICY=PASSIVE`` (which
``python -m tactile_bench`` sets unless the environment already does).

Run as ``python -m tactile_bench.bench.threads CHECKPOINT DATA THREADS REPEATS``; prints
one JSON line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from tactile_bench.bench.sampling import Case, run_case
from tactile_bench.data.braille import BrailleSet
from tactile_bench.translators.diffusion import DiffusionTranslator

# name -> (threads, OMP_WAIT_POLICY or None for the runtime's default)
SETTINGS: dict[str, tuple[int, str | None]] = {
    "1 thread": (1, None),
    "2 threads, OMP_WAIT_POLICY=ACTIVE (GNU OpenMP's default)": (2, "ACTIVE"),
    "2 threads, OMP_WAIT_POLICY=PASSIVE (the CLI's default)": (2, "PASSIVE"),
}


def thread_settings(translator: Any, data: Any, repeats: int) -> list[dict[str, Any]]:
    """Images/s of ``translator``'s default sampler on ``data`` under each of ``SETTINGS``."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="tb_bench_threads_") as tmp:
        model_path = translator.save(Path(tmp) / "translator.pt")
        data_path = data.save(Path(tmp) / "data.npz")
        for name, (threads, policy) in SETTINGS.items():
            env = dict(os.environ)
            env.pop("OMP_WAIT_POLICY", None)
            if policy:
                env["OMP_WAIT_POLICY"] = policy
            cmd = [
                sys.executable,
                "-m",
                "tactile_bench.bench.threads",
                str(model_path),
                str(data_path),
                str(threads),
                str(repeats),
            ]
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                tail = done.stderr.strip().splitlines()[-1:] or ["no output"]
                rows.append({"setting": name, "error": tail[0]})
                continue
            result = json.loads(done.stdout.strip().splitlines()[-1])
            rows.append({"setting": name, "threads": threads, "omp_wait_policy": policy, **result})
    ok = [r for r in rows if "error" not in r]
    if ok:
        base = ok[0]["images_per_s"]
        for row in ok:
            row["vs_first"] = row["images_per_s"] / base
    return rows


def _probe(model_path: str, data_path: str, threads: int, repeats: int) -> dict[str, Any]:
    import torch

    torch.set_num_threads(threads)
    model = DiffusionTranslator.load(model_path).eval()
    row = run_case(
        model, BrailleSet.load(data_path), Case(model.config.sampler, model.config.steps), repeats
    )
    keep = ("sampler", "steps", "images", "images_per_s", "images_per_cpu_s", "ssim")
    return {k: row[k] for k in keep}


if __name__ == "__main__":
    model_arg, data_arg, threads_arg, repeats_arg = sys.argv[1:5]
    print(json.dumps(_probe(model_arg, data_arg, int(threads_arg), int(repeats_arg))))
