"""The gap diagnosis at its defaults: wall seconds, where they go, peak memory (issue 47).

``N`` fresh pairs are rendered as ``export-pairs --generate N`` renders them
(``diagnose.commands.generate_pairs``, every braille character, the classifier grid, the
``digit`` surrogate playing real), written in the paired layout and read back as
``diagnose PAIRS`` reads them, then diagnosed in this process as the command does by default
(fit fraction 0.5, every candidate, the downstream classifiers on). The row holds the total
wall seconds, each step's (``where``, ``which``, ``how_far``, ``samples``, ``report``), the
peak resident memory, the diagnosis's own breakdown of its timed spans
(``diagnose.breakdown``) and the CPU capability torch runs on.

Run in the ``bench`` process, the diagnosis inherits its OpenMP wait policy (the CLI sets
``PASSIVE`` unless the environment sets one; ``diagnose`` keeps the environment's): the
row records the policy it ran under.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from tactile_bench.bench.timing import peak_memory
from tactile_bench.diagnose.commands import generate_pairs
from tactile_bench.diagnose.paired import from_braille_set, load_paired, write_paired
from tactile_bench.diagnose.run import diagnose, selected_effects
from tactile_bench.geometry.braille import CHARACTERS

#: spans of the breakdown shown in bench.md (bench.json keeps them all)
TOP_SPANS = 12
#: the steps ``diagnose`` times on its own, in its order
STEPS = ("where", "which", "how_far", "samples", "report")
#: RSS sampling interval: the run is long, a coarser sample costs it less
RSS_INTERVAL_S = 0.02


def diagnosis_row(
    n_pairs: int,
    size: int = 64,
    seed: int = 0,
    candidates: Sequence[str] | None = None,
    downstream: bool = True,
    progress: bool = False,
) -> dict[str, Any]:
    """One diagnosis of ``n_pairs`` fresh pairs at ``size`` px, timed (module docstring);
    ``candidates`` None: the command's default, every candidate."""
    with tempfile.TemporaryDirectory(prefix="tb_bench_diagnosis_") as tmp:
        t0 = time.perf_counter()
        pairs = generate_pairs(n_pairs, CHARACTERS, size=size, seed=seed, progress=progress)
        root = write_paired(Path(tmp) / "pairs", from_braille_set(pairs, CHARACTERS))
        data = load_paired(root)
        generate_s = time.perf_counter() - t0
        with peak_memory(RSS_INTERVAL_S) as mem:
            w0, c0 = time.perf_counter(), time.process_time()
            result = diagnose(
                data,
                Path(tmp) / "out",
                downstream=downstream,
                candidates=candidates,
                seed=seed,
                progress=progress,
            )
            wall_s, cpu_s = time.perf_counter() - w0, time.process_time() - c0
    spans = result.timing_s["breakdown"]
    return {
        "pairs": len(data),
        "size": data.size,
        "fit_fraction": result.split.fit_fraction,
        "candidates": "default (every candidate)" if candidates is None else list(candidates),
        "downstream": downstream,
        "generate_s": generate_s,
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "steps_s": {k: result.timing_s[k] for k in STEPS if k in result.timing_s},
        "which_s": result.timing_s["which"],
        "how_far_s": result.timing_s["how_far"],
        "peak_rss_mib": mem.peak_mib,
        "peak_rss_above_start_mib": mem.delta_mib,
        "rss_source": mem.source,
        "top_spans": [{"span": name, **row} for name, row in list(spans.items())[:TOP_SPANS]],
        "breakdown": spans,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch_threads": torch.get_num_threads(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
        "selected": list(selected_effects(result.which)),
        "unexplained": result.which.unexplained,
    }


def diagnosis_markdown(row: dict[str, Any]) -> list[str]:
    """bench.md's section: the run's figures, then its top spans."""
    total = sum(r["seconds"] for r in row["breakdown"].values()) or 1.0
    steps = ", ".join(f"{k} {v:.1f} s" for k, v in row["steps_s"].items())
    candidates = row["candidates"]
    lines = [
        "## Gap diagnosis (`diagnose` at its defaults)",
        "",
        f"{row['pairs']} fresh pairs of {row['size']} x {row['size']} px (as `export-pairs "
        f"--generate {row['pairs']}` renders them, {row['generate_s']:.1f} s to render, "
        f"write and read back), fit fraction {row['fit_fraction']:g}, candidates: "
        f"{candidates if isinstance(candidates, str) else ', '.join(candidates)}, downstream "
        f"classifiers {'on' if row['downstream'] else 'off'}; in the bench's process on "
        f"{row['cpu_capability']} with {row['torch_threads']} torch thread(s), "
        f"OMP_WAIT_POLICY {row['omp_wait_policy'] or 'unset'}.",
        "",
        f"- **{row['wall_s']:.1f} s** wall ({row['cpu_s']:.1f} CPU-s): {steps}",
        f"- peak resident memory {row['peak_rss_mib']:.0f} MiB "
        f"({row['peak_rss_above_start_mib']:.0f} MiB above the start)",
        f"- selected: {', '.join(row['selected']) or 'nothing'}; unexplained "
        f"{row['unexplained']:.3f}",
        "",
        f"Where the time went (top {len(row['top_spans'])} spans; a span's seconds exclude "
        "the spans inside it, so they add up to the total; inclusive seconds count them):",
        "",
    ]
    rows = [
        [
            f"`{r['span']}`",
            r["calls"],
            f"{r['seconds']:.2f}",
            f"{100 * r['seconds'] / total:.1f} %",
            f"{r['inclusive_seconds']:.2f}",
        ]
        for r in row["top_spans"]
    ]
    header = ["span", "calls", "seconds", "share", "inclusive s"]
    lines += ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return [*lines, ""]
