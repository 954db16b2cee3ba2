"""Benchmark of this machine: simulation, diffusion sampling, training; ratios side by side.

Entry point: ``python -m tactile_bench bench [--quick] [--diffusion CKPT]`` (``commands``),
or ``run.run_bench`` in-process.
"""

from tactile_bench.bench.run import BenchConfig, run_bench

__all__ = ["BenchConfig", "run_bench"]
