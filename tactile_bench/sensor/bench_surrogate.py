"""Throughput of the surrogate DIGIT: images per second, whole profile and each effect alone.

``surrogate_throughput`` renders ``n`` braille contacts of the classifier protocol (64 px
images from 128 px heights, as the benchmark builds them) and prints a table. Each figure is
the best of ``repeats`` runs, in wall time and in CPU time of this process: on a shared,
busy machine the CPU-time figure is the stabler one to compare versions with.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import classifier_protocol
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit


def _best(run: Callable[[], object], repeats: int) -> tuple[float, float]:
    """(wall, cpu) seconds of the fastest of ``repeats`` runs."""
    wall, cpu = float("inf"), float("inf")
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        run()
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def surrogate_throughput(
    n: int = 512,
    threads: int | None = None,
    profile: str = "digit",
    repeats: int = 2,
    per_effect: bool = True,
) -> dict[str, dict[str, float]]:
    """Images/s of ``SurrogateDigit.from_profile(profile).render`` on ``n`` contacts.

    Returns ``{row: {"img_s": wall-clock images/s, "img_cpu_s": images per CPU second}}``
    for rows ``"full"`` (the profile), ``"no_effects"`` (render_height + sim shading) and,
    with ``per_effect``, each enabled effect alone. ``threads`` sets torch's intra-op
    threads for the run (restored afterwards); None keeps the current setting.
    """
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        chars = tuple(CHARACTERS)
        bank = build_bank(chars)
        protocol = classifier_protocol(chars)
        step = max(1, len(protocol) // n)
        poses = protocol.index(torch.arange(0, step * n, step).clamp(max=len(protocol) - 1))
        gel = GelSpec()
        full = SurrogateDigit.from_profile(profile)
        rows = {"full": full, "no_effects": full.only()}
        if per_effect:
            rows |= {name: full.only(name) for name in full.effects_enabled}
        full.render(bank, poses.index(slice(0, 32)), gel)  # warm caches and allocator
        out: dict[str, dict[str, float]] = {}
        print(f"surrogate '{profile}', {len(poses)} contacts, {torch.get_num_threads()} thread(s)")
        print(f"  {'':22s} {'img/s':>8s} {'img/cpu-s':>10s}")
        for name, surrogate in rows.items():

            def run(s: SurrogateDigit = surrogate) -> object:
                return s.render(bank, poses, gel, torch.Generator().manual_seed(0))

            wall, cpu = _best(run, repeats)
            out[name] = {"img_s": len(poses) / wall, "img_cpu_s": len(poses) / max(cpu, 1e-9)}
            print(f"  {name:22s} {out[name]['img_s']:8.0f} {out[name]['img_cpu_s']:10.0f}")
        return out
    finally:
        torch.set_num_threads(previous)


if __name__ == "__main__":
    surrogate_throughput()
