"""End-to-end simulation throughput of the two dataset builders, timed span by span.

A benchmark of the builders of the data layer, so it lives with the benchmarks (``bench``),
above the layers it measures.

``braille_throughput(n)`` and ``object_throughput(n)`` build ``n`` braille contacts or ``n``
pretraining-object frames exactly as the pipeline's ``braille_data`` and ``ycb_slide_data``
stages do (same functions, same defaults: sim depth, sim image and surrogate-real image of
every contact or frame) and time every span with ``sensor.timing``. Both include writing
the results, since both stages always write them (``braille_data`` saves each set; the
corpus builder writes its shards), into a temporary directory deleted afterwards.

Both run on torch's thread count, as the builders do: braille contacts in that many Python
threads (``render_braille_set``), object frames in that many worker processes
(``build_ycb_slide_standin``); each gives the same data as one thread.

Returned: ``{"n", "wall_s", "per_s", "cpu_s", "per_cpu_s", "threads", "load", "spans",
"spans_cpu"}`` with ``spans`` the wall seconds of each timed span (exclusive of the spans
inside it; ``other`` is the untimed rest) and ``spans_cpu`` the same in CPU seconds of the
thread that ran the span (``cpu_s`` is the whole process's, worker processes included).
With several threads or processes the span times are summed over them (the wall times
then add up to more than ``wall_s``). ``load`` is ``os.getloadavg()`` at the start: on a
shared machine the wall figures are only as good as the machine is idle (and Linux's
per-session "autogroup" scheduling gives a session one share however many processes it
runs), the CPU figures are the stabler ones to compare versions with.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from tactile_bench.data.braille import build_braille_sets
from tactile_bench.data.ycb_slide import StandinConfig, build_ycb_slide_standin
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.sensor.timing import SpanTimer, timed_span

#: proportions of the ``braille_data`` stage's default sets (finetune, test, classifier,
#: classifier_test): 1080 + 837 + 10692 + 837 = 13446 contacts.
BRAILLE_DEFAULT_SETS = (1080, 837, 10692, 837)


def _split(n: int, weights: tuple[int, ...]) -> list[int]:
    """``n`` split over ``weights`` proportionally (largest remainders), every part >= 1."""
    raw = [n * w / sum(weights) for w in weights]
    parts = [int(r) for r in raw]
    order = sorted(range(len(raw)), key=lambda i: raw[i] - parts[i], reverse=True)
    for i in order[: n - sum(parts)]:
        parts[i] += 1
    for i in range(len(parts)):  # an empty part borrows from the largest
        if parts[i] == 0:
            parts[i] = 1
            parts[parts.index(max(parts))] -= 1
    return parts


def _report(n: int, timer: SpanTimer, wall: float, cpu: float, load: tuple) -> dict[str, Any]:
    spans = dict(sorted(timer.wall.items(), key=lambda kv: -kv[1]))
    spans_cpu = {k: timer.cpu[k] for k in spans}
    spans["other"] = max(0.0, wall - sum(timer.wall.values()))
    spans_cpu["other"] = max(0.0, cpu - sum(timer.cpu.values()))
    return {
        "n": n,
        "wall_s": wall,
        "per_s": n / wall if wall > 0 else float("inf"),
        "cpu_s": cpu,
        "per_cpu_s": n / cpu if cpu > 0 else float("inf"),
        "threads": torch.get_num_threads(),
        "load": load,
        "spans": spans,
        "spans_cpu": spans_cpu,
    }


def braille_throughput(n: int, seed: int = 0, real_sensor: str = "digit") -> dict[str, Any]:
    """Build ``n`` braille contacts as the ``braille_data`` stage does, and time it.

    The contacts are split over the stage's four sets in its default proportions (at
    ``n = 13446`` exactly the default stage); the height-field bank is ray-cast as the
    stage does (span ``bank``) and the sets are saved to a temporary directory (``io``).
    """
    if n < len(BRAILLE_DEFAULT_SETS):
        raise TactileBenchError(f"braille_throughput: n must be >= 4, got {n}")
    n_ft, n_te, n_cl, n_ct = _split(n, BRAILLE_DEFAULT_SETS)
    chars = tuple(CHARACTERS)
    grid = 180 * len(chars)  # the fine-tune/test grid: the first two sets are drawn from it
    if n_ft + n_te > grid or n_cl > 396 * len(chars):
        raise TactileBenchError(f"braille_throughput: n = {n} exceeds the protocols' grids")
    load = os.getloadavg()
    with SpanTimer() as timer, tempfile.TemporaryDirectory() as tmp:
        w0, c0 = time.perf_counter(), time.process_time()
        gel = GelSpec()
        with timed_span("bank"):
            bank = build_bank(chars, BrailleSpec())
        real = SurrogateDigit.from_profile(real_sensor)
        sets = build_braille_sets(
            bank,
            gel,
            SimOptics(),
            sim_background(gel.size),
            real,
            seed=seed,
            chars=chars,
            n_finetune=n_ft,
            n_test=n_te,
            n_classifier=n_cl,
            n_classifier_test=n_ct,
            progress=False,
        )
        with timed_span("io"):
            for name, s in sets.items():
                s.save(Path(tmp) / f"{name}.npz")
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    built = sum(len(s) for s in sets.values())
    return _report(built, timer, wall, cpu, load)


def format_report(name: str, report: dict[str, Any]) -> str:
    """A few lines: rate, then each span's wall and CPU seconds and share."""
    lines = [
        f"{name}: {report['n']} in {report['wall_s']:.2f} s wall = {report['per_s']:.0f}/s "
        f"({report['cpu_s']:.2f} s CPU = {report['per_cpu_s']:.0f}/CPU-s), "
        f"{report['threads']} thread(s), load {report['load'][0]:.2f}"
    ]
    for span, wall in report["spans"].items():
        cpu = report["spans_cpu"][span]
        share = 100 * wall / report["wall_s"] if report["wall_s"] else 0.0
        lines.append(f"  {span:32s} {wall:8.3f} s {cpu:8.3f} cpu-s {share:5.1f}%")
    return "\n".join(lines)


def object_throughput(
    n: int,
    seed: int = 0,
    real_sensor: str = "digit",
    objects: Sequence[str] | None = None,
    workers: int | None = None,
) -> dict[str, Any]:
    """Build an ``n``-pair YCB-Slide stand-in corpus as ``ycb_slide_data`` does, and time it.

    All ten objects (or ``objects``), five trajectories each, so the per-object set-up
    (meshes, exposed surface, trajectories, ray-tracing structure) is paid in full; the
    builder writes its shards (``io``). ``n`` is the corpus size asked for; the report's
    ``n`` counts the pairs written: frames where the sensor would collide with the object
    are dropped (a few %), but their rendering is timed too. ``workers`` as in
    ``build_ycb_slide_standin`` (default: one process per torch thread); with several,
    the span times are summed over the processes (so they add up to more than the wall).
    """
    if n < 10:
        raise TactileBenchError(f"object_throughput: n must be >= 10, got {n}")
    load = os.getloadavg()
    with SpanTimer() as timer, tempfile.TemporaryDirectory() as tmp:
        w0, c0 = time.perf_counter(), time.process_time()
        objs = tuple(objects) if objects is not None else StandinConfig().objects
        manifest = build_ycb_slide_standin(
            tmp,
            config=StandinConfig(n_pairs=n, seed=seed, objects=objs),
            gel=GelSpec(),
            real_sensor=SurrogateDigit.from_profile(real_sensor),
            progress=False,
            workers=workers,
        )
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0 + timer.other_cpu
    report = _report(manifest["n_train"] + manifest["n_test"], timer, wall, cpu, load)
    report["frames_dropped"] = manifest["frames_dropped"]
    return report
