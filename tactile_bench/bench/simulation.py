"""Contact simulation throughput: braille contacts and pretraining-object frames per second.

A contact costs three products, each timed on its own as a phase (result key ``phases``;
"stage" means a recipe stage only): ``depth``, the sim depth (what TACTO gives),
``sim_image`` (``SimOptics``) and ``real_image``, the surrogate "real" image
(``SurrogateDigit``). The headline figure is the end-to-end builder the pipeline runs
(``render_braille_set`` for braille, ``build_ycb_slide_standin`` for the objects, shard
writing included), at 1x, 2x and 4x the work so a non-linear cost shows. One-off set-up
(the braille height-field bank, an object's mesh, ray-casting scene and trajectories) is
timed apart: it does not grow with the number of contacts.

The phases are timed on one torch thread, as the builders run them (one Python thread or
one worker process per core, torch single-threaded in each): their rates are per core.
Objects are built at least at the size of one object of the default corpus (800 frames at
4x): a build pays each object's set-up (meshes, exposed surface, trajectories, ray-casting
scene) once, so a 200-frame build mostly measured set-up. The worker processes' start-up
(spawn and imports, once per process: the pool is kept) lands in an untimed warm-up build,
reported as ``first_build_s``; the workers' CPU time is added to the builds' ``cpu_s``.
``marginal`` is the rate of the frames a bigger build adds (2x -> 4x): the fixed costs of a
build (set-up, dispatch) cancel out of it.
"""

from __future__ import annotations

import itertools
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_bench.bench.timing import Timing, measure, torch_threads
from tactile_bench.data.braille import render_braille_set
from tactile_bench.data.ycb_slide import StandinConfig, build_ycb_slide_standin, settle_press
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import Poses, finetune_test_protocol
from tactile_bench.geometry.objects import object_parts
from tactile_bench.geometry.trajectories import exposed_surface, sliding_trajectories
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.sensor.timing import SpanTimer

SCALES = (1, 2, 4)
#: frames of one object in the default corpus (8000 pairs over 10 objects): the objects'
#: 4x build is at least this big, so the per-object set-up weighs as in a real build
AMORTISED_FRAMES = StandinConfig().frames_per_trajectory * StandinConfig().n_trajectories


def _poses(n: int) -> Poses:
    """``n`` contacts spread over the whole fine-tune/test grid (all characters, yaws, depths)."""
    grid = finetune_test_protocol(CHARACTERS)
    idx = torch.arange(n) * len(grid) // max(n, 1)
    return grid.index(idx % len(grid))


def braille(n: int, repeats: int, profile: str = "digit") -> dict[str, Any]:
    """Per-phase cost and end-to-end contacts/s of braille contacts, at 1x, 2x, 4x ``n``."""
    gel = GelSpec()
    setup = measure(lambda: build_bank(CHARACTERS), work=len(CHARACTERS), repeats=1)
    bank = build_bank(CHARACTERS)
    real = SurrogateDigit.from_profile(profile)
    optics = SimOptics()
    sim_bg = sim_background(gel.size)
    real_bg = real.background(gel.size)
    poses = _poses(n)
    depth = to_depth(render_height(bank, poses, gel), gel)

    def gen() -> torch.Generator:
        return torch.Generator().manual_seed(0)

    with torch_threads(1):  # as the builder runs them: one thread per core
        phases = {
            "depth": measure(lambda: to_depth(render_height(bank, poses, gel), gel), n, repeats),
            "sim_image": measure(lambda: optics.render(depth, sim_bg, gen(), gel), n, repeats),
            "real_image": measure(lambda: real.render(bank, poses, gel, gen()), n, repeats),
        }
    scaling = {}
    for k in SCALES:
        p = _poses(n * k)
        scaling[f"{k}x"] = measure(
            lambda p=p: render_braille_set(
                bank, p, gel, optics, sim_bg, real, real_bg, gen(), gen()
            ),
            n * k,
            repeats,
        ).to_dict()
    phase_total = sum(t.median_wall_s for t in phases.values())
    return {
        "contacts": n,
        "setup_bank_s": setup.median_wall_s,
        "phases": {
            name: {**t.to_dict(), "share": t.median_wall_s / phase_total}
            for name, t in phases.items()
        },
        "scaling": scaling,
        "contacts_per_s": scaling[f"{SCALES[-1]}x"]["per_s"],
    }


def _object_scene(name: str, frames: int, gel: GelSpec) -> tuple[MeshDepthRenderer, Any]:
    parts = object_parts(name, 0)
    trajectory = sliding_trajectories(exposed_surface(parts), name, 1, frames, seed=0)[0]
    import trimesh

    return MeshDepthRenderer.from_trimesh(trimesh.util.concatenate(parts), gel), trajectory


def objects(
    n: int,
    repeats: int,
    object_names: tuple[str, ...] = ("004_sugar_box",),
    profile: str = "digit",
    amortised: int = AMORTISED_FRAMES,
) -> dict[str, Any]:
    """Per-phase cost (``n`` frames) and end-to-end frames/s of the YCB-Slide stand-in.

    The builds run at 1x, 2x, 4x of ``n`` frames an object, or of ``amortised / 4`` when
    that is more (0: exactly ``n``); the headline ``frames_per_s`` is the 4x build's.
    """
    gel = GelSpec()
    real = SurrogateDigit.from_profile(profile)
    optics = SimOptics()
    sim_bg = sim_background(gel.size)
    setup, phases = _object_phases(object_names[0], n, repeats, gel, real, optics, sim_bg)
    scaling, first_build_s = _build_scaling(object_names, n, repeats, amortised, real)
    phase_total = sum(t.median_wall_s for t in phases.values())
    big = scaling[f"{SCALES[-1]}x"]
    return {
        "frames": n,
        "objects": list(object_names),
        "setup_scene_s": setup.median_wall_s,
        "first_build_s": first_build_s,
        "phases": {
            name: {**t.to_dict(), "share": t.median_wall_s / phase_total}
            for name, t in phases.items()
        },
        "scaling": scaling,
        "marginal": _marginal_rates(scaling),
        "frames_per_s": big["per_s"],
    }


def _object_phases(
    name: str,
    n: int,
    repeats: int,
    gel: GelSpec,
    real: SurrogateDigit,
    optics: SimOptics,
    sim_bg: torch.Tensor,
) -> tuple[Timing, dict[str, Timing]]:
    """Scene set-up, then each phase on ``n`` frames of one object, one thread as a worker."""
    setup = measure(lambda: _object_scene(name, n, gel)[0].close(), work=1, repeats=1)
    renderer, traj = _object_scene(name, n, gel)
    press = traj.press_mm.astype(np.float64)
    true_h, _, _ = settle_press(renderer, traj.poses, press)

    def depth() -> torch.Tensor:  # both poses settled, as the builder does
        settle_press(renderer, traj.poses, press)
        meas_h, _, _ = settle_press(renderer, traj.measured, press)
        return to_depth(meas_h, gel)

    d = depth()

    def gen() -> torch.Generator:
        return torch.Generator().manual_seed(0)

    with torch_threads(1):  # as each worker process runs them
        phases = {
            "depth": measure(depth, n, repeats),
            "sim_image": measure(lambda: optics.render(d, sim_bg, gen(), gel), n, repeats),
            "real_image": measure(lambda: real.render_surface(true_h, gel, gen()), n, repeats),
        }
    renderer.close()
    return setup, phases


def _build_scaling(
    object_names: tuple[str, ...], n: int, repeats: int, amortised: int, real: SurrogateDigit
) -> tuple[dict[str, dict[str, Any]], float]:
    """Whole stand-in builds at each of ``SCALES``, and the first build's time kept apart."""
    per_object = amortised // SCALES[-1] if amortised else 0
    base = max(n, per_object * len(object_names))
    scaling: dict[str, dict[str, Any]] = {}
    runs = itertools.count()
    first_build_s = 0.0
    with tempfile.TemporaryDirectory(prefix="tb_bench_") as tmp:
        for k in SCALES:
            config = StandinConfig(n_pairs=base * k, objects=object_names)

            def build(config: StandinConfig = config, runs: Iterator[int] = runs) -> float:
                # a fresh directory each time: the builder would skip finished shards
                with SpanTimer() as timer:  # workers report their CPU time to it
                    build_ycb_slide_standin(
                        Path(tmp) / f"run_{next(runs)}",
                        config=config,
                        real_sensor=real,
                        progress=False,
                    )
                return timer.other_cpu

            if k == SCALES[0]:  # worker start-up, imports, caches: once, apart
                w0 = time.perf_counter()
                build()
                first_build_s = time.perf_counter() - w0
            work = config.frames_per_trajectory * config.n_trajectories * len(object_names)
            scaling[f"{k}x"] = measure_with_workers(build, work, repeats).to_dict()
    return scaling, first_build_s


def _marginal_rates(scaling: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Frames a second (and a CPU-second) the largest build adds over the one before it."""
    big, mid = scaling[f"{SCALES[-1]}x"], scaling[f"{SCALES[-2]}x"]
    extra = big["work"] - mid["work"]
    d_wall = big["median_wall_s"] - mid["median_wall_s"]
    d_cpu = big["work"] / big["per_cpu_s"] - mid["work"] / mid["per_cpu_s"]
    return {
        "frames_per_s": extra / d_wall if d_wall > 0 else float("inf"),
        "frames_per_cpu_s": extra / d_cpu if d_cpu > 0 else float("inf"),
    }


def measure_with_workers(build: Callable[[], float], work: float, repeats: int) -> Timing:
    """``measure(build)`` with the CPU time the worker processes report added to each
    repetition's (``time.process_time`` sees only this process)."""
    worker_cpu: list[float] = []
    timing = measure(lambda: worker_cpu.append(build()), work, repeats, warmup=0)
    timing.cpu_s = [c + w for c, w in zip(timing.cpu_s, worker_cpu, strict=True)]
    return timing


def linearity(scaling: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Time at k x the work divided by k x the time at 1x: 1.0 is linear, > 1 superlinear."""
    base = scaling["1x"]["median_wall_s"]
    return {key: row["median_wall_s"] / (int(key[:-1]) * base) for key, row in scaling.items()}


__all__ = ["SCALES", "braille", "linearity", "measure_with_workers", "objects"]
