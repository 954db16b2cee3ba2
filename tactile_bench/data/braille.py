"""The braille data sets: (sim depth, sim image, real image) triples of the same contacts.

The paper pairs every real DIGIT press with TACTO's depth of the same commanded contact. We
do the same with the simulator (``SimOptics`` over the depth) and a "real" sensor (by default
the surrogate DIGIT), keeping the *sim* depth, never the real sensor's internal geometry: a
translator conditions on what TACTO gives, exactly as in the paper.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np
import torch
from tqdm.auto import tqdm

from tactile_bench.data.paired import Pairs
from tactile_bench.data.pixels import to_uint8
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS
from tactile_bench.geometry.contacts import (
    Poses,
    classifier_protocol,
    classifier_test_protocol,
    finetune_test_protocol,
)
from tactile_bench.io import atomic_write_npz, load_npz
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import HeightFieldBank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import timed_span

_POSE_KEYS = ("labels", "x_mm", "y_mm", "yaw_deg", "press_mm")
#: the classifier_test contacts rendered by a second unit (``build_braille_sets(second_unit=)``)
SECOND_UNIT_SET = "classifier_test_second_unit"
_KEYS = ("depth", "sim", "real", "sim_background", "real_background") + tuple(
    f"pose_{k}" for k in _POSE_KEYS
)


class RealSensor(Protocol):
    """What the builder needs of the "real" sensor (e.g. ``sensor.surrogate.SurrogateDigit``)."""

    def background(self, size: int) -> torch.Tensor: ...

    def render(
        self,
        bank: HeightFieldBank,
        poses: Poses,
        gel: GelSpec,
        generator: torch.Generator | None,
    ) -> torch.Tensor: ...


@dataclass
class BrailleSet(Pairs):
    """N contacts: sim depth (N,1,S,S) mm, sim and real images (N,3,S,S) uint8, and poses.

    ``labels`` index the character tuple the set was built with (``CHARACTERS`` by default).
    One sim and one real no-contact frame (3,S,S) serve every contact; shape checks,
    ``subset`` and ``foreground`` are ``data.paired.Pairs``'s.
    """

    PER_PAIR: ClassVar[tuple[str, ...]] = ("depth", "sim", "real", "labels")

    depth: torch.Tensor
    sim: torch.Tensor
    real: torch.Tensor
    labels: torch.Tensor
    poses: Poses
    sim_background: torch.Tensor
    real_background: torch.Tensor

    def __post_init__(self) -> None:
        self._check_pairs(poses=self.poses)

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        return {"poses": self.poses.index(index)}

    def save(self, path: str | os.PathLike) -> Path:
        """One uncompressed .npz, written to a temporary file and renamed into place."""
        arrays = {
            "depth": self.depth.float().numpy(),
            "sim": self.sim.numpy(),
            "real": self.real.numpy(),
            "sim_background": self.sim_background.numpy(),
            "real_background": self.real_background.numpy(),
        }
        arrays.update({f"pose_{k}": getattr(self.poses, k).numpy() for k in _POSE_KEYS})
        return atomic_write_npz(Path(path), **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> BrailleSet:
        """Read a set written by ``save``; a missing or corrupt file is a ``TactileBenchError``."""
        a = load_npz(Path(path), _KEYS)
        try:
            poses = Poses(**{k: torch.from_numpy(a[f"pose_{k}"]) for k in _POSE_KEYS})
            return cls(
                depth=torch.from_numpy(a["depth"]).float(),
                sim=to_uint8(torch.from_numpy(a["sim"])),
                real=to_uint8(torch.from_numpy(a["real"])),
                labels=poses.labels,
                poses=poses,
                sim_background=to_uint8(torch.from_numpy(a["sim_background"])),
                real_background=to_uint8(torch.from_numpy(a["real_background"])),
            )
        except (TactileBenchError, RuntimeError, TypeError, ValueError) as exc:
            raise TactileBenchError(f"{path}: not a valid braille set ({exc})") from None


def _quotas(total: int, groups: int, rng: np.random.Generator) -> np.ndarray:
    """``total`` split over ``groups`` as evenly as possible; the remainder goes to random ones."""
    q = np.full(groups, total // groups)
    q[rng.choice(groups, total % groups, replace=False)] += 1
    return q


def draw_disjoint(
    labels: torch.Tensor, sizes: Sequence[int], n_classes: int, seed: int
) -> list[torch.Tensor]:
    """Disjoint, per-class stratified draws of ``sizes`` indices from ``labels``; seeded."""
    rng = np.random.default_rng(seed)
    quotas = [_quotas(n, n_classes, rng) for n in sizes]
    picks: list[list[np.ndarray]] = [[] for _ in sizes]
    lab = labels.numpy()
    for c in range(n_classes):
        pool = rng.permutation(np.flatnonzero(lab == c))
        need = sum(int(q[c]) for q in quotas)
        if need > len(pool):
            raise TactileBenchError(
                f"braille sets: {need} contacts of class {c} requested, the grid has {len(pool)}"
            )
        start = 0
        for k, q in enumerate(quotas):
            picks[k].append(pool[start : start + int(q[c])])
            start += int(q[c])
    return [torch.from_numpy(np.sort(np.concatenate(p))).long() for p in picks]


def render_braille_set(
    bank: HeightFieldBank,
    poses: Poses,
    gel: GelSpec,
    sim_optics: SimOptics,
    sim_background: torch.Tensor,
    real_sensor: RealSensor,
    real_background: torch.Tensor,
    sim_generator: torch.Generator,
    real_generator: torch.Generator,
    chunk: int = 128,
    bar: tqdm | None = None,
    threads: int | None = None,
) -> BrailleSet:
    """Render ``poses`` with the simulator (depth and image) and the real sensor, in chunks.

    With ``threads`` > 1 (default: torch's thread count) the contacts are split into that
    many contiguous parts rendered in parallel Python threads (torch's kernels release the
    GIL). Torch itself runs on one thread meanwhile (restored afterwards). Each part's
    generators are first advanced past the parts before it (``skip_random``), so the set is
    the one a sequential render gives, and the generators end where a sequential render
    leaves them. Needs a real sensor with ``skip_random`` and ``RENDER_CHUNK``
    (``SurrogateDigit``); others render sequentially.
    """
    threads = torch.get_num_threads() if threads is None else threads
    unit = getattr(real_sensor, "RENDER_CHUNK", None)
    n = len(poses)
    skips = hasattr(real_sensor, "skip_random") and hasattr(sim_optics, "skip_random")
    parallel = threads > 1 and unit is not None and skips and n > unit
    args = (bank, poses, gel, sim_optics, sim_background.float(), real_sensor, chunk, bar)
    previous = torch.get_num_threads()
    # torch on one thread either way: on ops this small, intra-op threads cost more than they
    # give (and busy-wait for the CPU when the machine is shared; docs/results/code_figures.md)
    torch.set_num_threads(1)
    try:
        if parallel:
            parts = _render_parallel(args, sim_generator, real_generator, threads, unit)
        else:
            parts = [_render_range(args, 0, n, sim_generator, real_generator)]
    finally:
        torch.set_num_threads(previous)
    depth, sim, real = ([x for p in parts for x in p[i]] for i in range(3))
    s = gel.size
    return BrailleSet(
        depth=torch.cat(depth) if depth else torch.zeros(0, 1, s, s),
        sim=torch.cat(sim) if sim else torch.zeros(0, 3, s, s, dtype=torch.uint8),
        real=torch.cat(real) if real else torch.zeros(0, 3, s, s, dtype=torch.uint8),
        labels=poses.labels,
        poses=poses,
        sim_background=sim_background,
        real_background=real_background,
    )


_Parts = tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]


def _sim_depths(args: tuple, start: int, stop: int) -> list[torch.Tensor]:
    """The sim depth of contacts ``start:stop``, a tensor a ``chunk``: it draws nothing."""
    bank, poses, gel, *_, chunk, _ = args
    depths = []
    for k in range(start, stop, chunk):
        with timed_span("sim.height"):
            h = render_height(bank, poses.index(slice(k, min(k + chunk, stop))), gel)
        with timed_span("sim.depth"):
            depths.append(to_depth(h, gel, inplace=True))
    return depths


def _render_range(
    args: tuple,
    start: int,
    stop: int,
    sim_gen: torch.Generator,
    real_gen: torch.Generator,
    depths: list[torch.Tensor] | None = None,
) -> _Parts:
    """Depth, sim and real images of contacts ``start:stop``, ``chunk`` at a time
    (``depths``: their ``_sim_depths``, when already made)."""
    bank, poses, gel, sim_optics, sim_background, real_sensor, chunk, bar = args
    depth = _sim_depths(args, start, stop) if depths is None else depths
    sim, real = [], []
    for k, d in zip(range(start, stop, chunk), depth, strict=True):
        part = poses.index(slice(k, min(k + chunk, stop)))
        with timed_span("sim.optics"):
            s = sim_optics.render(d, sim_background, sim_gen, gel)
        with timed_span("uint8"):
            sim.append(to_uint8(s))
        r = real_sensor.render(bank, part, gel, real_gen)
        with timed_span("uint8"):
            real.append(to_uint8(r[0] if isinstance(r, tuple) else r))
        if bar is not None:
            bar.update(len(part))
    return depth, sim, real


def _clone(generator: torch.Generator) -> torch.Generator:
    return torch.Generator().set_state(generator.get_state())


def _render_parallel(
    args: tuple,
    sim_generator: torch.Generator,
    real_generator: torch.Generator,
    threads: int,
    unit: int,
) -> list[_Parts]:
    """``_render_range`` over ``threads`` parts in parallel threads (see render_braille_set).

    Parts start where a sequential render starts a batch of draws: on the real sensor's
    chunks (``unit``) when ``chunk`` is a multiple of it, else on ``chunk`` boundaries. The
    generators of part i + 1 are advanced (``skip_random``, batch by batch, a small share
    of a render) in this thread while the earlier parts render and part i + 1 makes its sim
    depths, which draw nothing: the skip then keeps no core waiting. The earlier parts get
    a few more contacts where the batches allow, for the skip's share of the cores.
    """
    _, poses, gel, sim_optics, _, real_sensor, chunk, _ = args
    n = len(poses)
    step = unit if chunk % unit == 0 else chunk
    cuts = [min(n, round(n * i / threads * 1.03 / step) * step) for i in range(threads)]
    cuts = sorted(set(cuts) | {n})
    parts = len(cuts) - 1
    results: list[_Parts | None] = [None] * parts
    errors: list[BaseException] = []
    gens: list[tuple[torch.Generator, torch.Generator] | None] = [None] * parts
    ready = [threading.Event() for _ in range(parts)]

    def work(i: int) -> None:
        try:
            depths = _sim_depths(args, cuts[i], cuts[i + 1])  # draws nothing: no need to wait
            ready[i].wait()
            if gens[i] is not None:  # else skipping failed: raised in the calling thread
                results[i] = _render_range(args, cuts[i], cuts[i + 1], *gens[i], depths)
        except BaseException as exc:  # re-raised in the calling thread below
            errors.append(exc)

    workers = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(parts)]
    for worker in workers:
        worker.start()
    sim_g, real_g = _clone(sim_generator), _clone(real_generator)
    try:
        for i in range(parts):
            gens[i] = (_clone(sim_g), _clone(real_g))
            ready[i].set()
            if i < parts - 1:
                for k in range(cuts[i], cuts[i + 1], step):  # the batches a render draws
                    m = min(step, cuts[i + 1] - k)
                    sim_optics.skip_random(m, gel, sim_g)
                    real_sensor.skip_random(m, gel, real_g)  # type: ignore[attr-defined]
    finally:
        for event in ready:
            event.set()
        for worker in workers:
            worker.join()
    if errors:
        raise errors[0]
    last = gens[-1]
    assert last is not None
    sim_generator.set_state(last[0].get_state())  # where a sequential render ends
    real_generator.set_state(last[1].get_state())
    return results  # type: ignore[return-value]


def build_braille_sets(
    bank: HeightFieldBank,
    gel: GelSpec,
    sim_optics: SimOptics,
    sim_background: torch.Tensor,
    real_sensor: RealSensor,
    seed: int,
    chars: Sequence[str] = CHARACTERS,
    n_finetune: int = 1080,
    n_test: int = 837,
    progress: bool = True,
    chunk: int = 128,
    n_classifier: int | None = None,
    n_classifier_test: int = 837,
    second_unit: RealSensor | None = None,
) -> dict[str, BrailleSet]:
    """The paper's sets: ``finetune``, ``test``, ``classifier`` and ``classifier_test``.

    ``finetune`` and ``test`` are disjoint draws, stratified per character, from the
    fine-tune/test grid (180 contacts a character); ``classifier`` is the whole classifier
    grid (396 a character), or a stratified draw of ``n_classifier`` from it for quick runs;
    ``classifier_test`` (``n_classifier_test``) are off-grid upright contacts on which the
    classifiers are tested (see ``classifier_test_protocol``). Each set's selection, sim
    noise and real-sensor randomness come from its own stream spawned from ``seed``, so one
    set does not shift when another's size changes.

    With ``second_unit``, ``classifier_test_second_unit`` holds the ``classifier_test``
    contacts again with that sensor as "real": the same depth and sim images (it draws the
    sim noise from ``classifier_test``'s stream), real images of another unit from a stream
    of its own, so every other set is the same with or without it.
    """
    chars = tuple(chars)
    if tuple(bank.chars) != chars:
        raise TactileBenchError(
            f"build_braille_sets: bank holds {''.join(bank.chars)!r}, asked for {''.join(chars)!r}"
        )
    select, *streams = np.random.SeedSequence(seed).spawn(10)
    grid = finetune_test_protocol(chars)
    ft_idx, te_idx = draw_disjoint(
        grid.labels, (n_finetune, n_test), len(chars), int(select.generate_state(1)[0])
    )
    classifier_grid = classifier_protocol(chars)
    if n_classifier is not None and n_classifier < len(classifier_grid):
        (cl_idx,) = draw_disjoint(
            classifier_grid.labels,
            (n_classifier,),
            len(chars),
            int(select.generate_state(2)[1]),
        )
        classifier_grid = classifier_grid.index(cl_idx)
    poses = {
        "finetune": grid.index(ft_idx),
        "test": grid.index(te_idx),
        "classifier": classifier_grid,
        "classifier_test": classifier_test_protocol(
            chars, n_classifier_test, int(select.generate_state(3)[2])
        ),
    }
    sim_bg = to_uint8(torch.as_tensor(sim_background))
    real_bg = to_uint8(real_sensor.background(gel.size))
    # (name, contacts, real sensor, its background, sim stream, real stream)
    jobs = [
        (name, p, real_sensor, real_bg, streams[2 * k], streams[2 * k + 1])
        for k, (name, p) in enumerate(poses.items())
    ]
    if second_unit is not None:  # stream 8 is its own: spawn(10) begins with spawn(9)'s nine
        unit_bg = to_uint8(second_unit.background(gel.size))
        contacts = poses["classifier_test"]
        jobs.append((SECOND_UNIT_SET, contacts, second_unit, unit_bg, streams[6], streams[8]))
    total = sum(len(job[1]) for job in jobs)
    out = {}
    with tqdm(total=total, desc="braille sets", unit="contact", disable=not progress) as bar:
        for name, p, sensor, background, *stream in jobs:
            gens = [torch.Generator().manual_seed(int(s.generate_state(1)[0])) for s in stream]
            out[name] = render_braille_set(
                bank, p, gel, sim_optics, sim_bg, sensor, background, *gens, chunk, bar
            )
    return out
