"""Benchmark of this machine: simulation, diffusion sampling, training; ratios side by side.

Entry point: ``python -m tactile_bench bench [--quick] [--diffusion CKPT]`` (``commands``),
or ``run.run_bench`` in-process.
"""

from __future__ import annotations

from typing import Any

__all__ = ["BenchConfig", "run_bench"]


def __getattr__(name: str) -> Any:
    """``BenchConfig`` and ``run_bench`` on first use: the CLI registers ``bench`` without
    importing Lightning, so a refused argument is answered in a second or two."""
    if name in __all__:
        from tactile_bench.bench import run

        return getattr(run, name)
    raise AttributeError(name)
