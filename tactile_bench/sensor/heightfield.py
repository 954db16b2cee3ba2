"""Height fields of the braille blocks, ray-cast once per character (Embree or pybullet).

A braille contact is a rigid transform of the block, so its depth image is a resampling of
the block's top-surface height field. We ray-cast that field once (vertical rays against the
mesh: Embree when installed, else pybullet DIRECT mode with the mesh as a static concave
collision shape; no OpenGL) and every contact afterwards is a ``grid_sample``
(``sensor.depth``).

Map layout: ``maps[l, 0, i, j]`` is the height (mm) relative to the block's top face of the
point x = -half + j * res, y = +half - i * res (row 0 is the far +y edge, as in an image seen
from above). 0 on the flat top, the dome height at dot peaks, ``far_mm`` (the block's bottom,
i.e. the table it stands on) off the block.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec, braille_mesh
from tactile_bench.io import atomic_write_npz, load_npz

_FORMAT = 1


def embree_available() -> bool:
    """Whether the fast backend can be used (``pip install embreex``)."""
    try:
        import embreex  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass
class HeightFieldBank:
    """One height map per label: ``maps`` (L, 1, H, W) float32 mm over a square extent."""

    maps: torch.Tensor
    chars: tuple[str, ...]
    half_extent_mm: float
    far_mm: float
    spec: BrailleSpec

    def __post_init__(self) -> None:
        if self.maps.dim() != 4 or self.maps.shape[:2] != (len(self.chars), 1):
            raise TactileBenchError(f"HeightFieldBank: maps must be (L, 1, H, W), L = {len(self)}")
        self.chars = tuple(self.chars)
        self.maps = self.maps.float().contiguous()
        self._top_max = self.maps.flatten(1).amax(1)

    def __len__(self) -> int:
        return len(self.chars)

    @property
    def resolution_mm(self) -> float:
        return 2 * self.half_extent_mm / (self.maps.shape[-1] - 1)

    @property
    def top_max(self) -> torch.Tensor:
        """(L,) highest point of each object (its dot peaks), mm above the top face."""
        return self._top_max

    def save(self, path: str | os.PathLike) -> None:
        """Cache the bank as an .npz (written atomically)."""
        atomic_write_npz(
            Path(path),
            maps=self.maps.numpy(),
            chars=np.array(self.chars),
            half_extent_mm=np.float64(self.half_extent_mm),
            far_mm=np.float64(self.far_mm),
            spec=np.array(json.dumps(asdict(self.spec))),
            format=np.int64(_FORMAT),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> HeightFieldBank:
        """Read a cached bank; a missing, corrupt or foreign file is a ``TactileBenchError``."""
        a = load_npz(Path(path), ("maps", "chars", "half_extent_mm", "far_mm", "spec", "format"))
        try:
            if int(a["format"]) != _FORMAT:
                raise ValueError(f"format {int(a['format'])}, expected {_FORMAT}")
            return cls(
                maps=torch.from_numpy(a["maps"].astype(np.float32)),
                chars=tuple(str(c) for c in a["chars"]),
                half_extent_mm=float(a["half_extent_mm"]),
                far_mm=float(a["far_mm"]),
                spec=BrailleSpec(**json.loads(str(a["spec"]))),
            )
        except (ValueError, TypeError, TactileBenchError) as e:
            raise TactileBenchError(f"{path}: not a valid height-field bank ({e})") from None


def raycast_heights(
    meshes: Sequence[tuple[np.ndarray, np.ndarray]],
    xs: np.ndarray,
    ys: np.ndarray,
    z_from: float,
    z_to: float,
    miss: float,
    num_threads: int | None = None,
    backend: str = "auto",
) -> np.ndarray:
    """Heights (M, len(ys), len(xs)) of the first hit of vertical rays cast down on M meshes.

    ``meshes`` are (vertices, faces) pairs. With Embree installed (``embreex``) the rays go
    through its watertight ("robust") intersector: the grid puts rays exactly through mesh
    vertices and edges, where the default one lets some of them slip through. Otherwise one
    pybullet DIRECT client (disconnected afterwards) holds one mesh at a time as a static
    concave shape; the same ray lists are reused for every mesh (building them costs as
    much as casting). Rays go in chunks of ``pybullet.MAX_RAY_INTERSECTION_BATCH_SIZE - 1``
    on ``num_threads`` threads (default: all cores, faster than Bullet's own choice, 0).
    Both give the same heights to ~1e-6 mm; Embree is the faster
    (docs/results/code_figures.md). Rays that miss get ``miss``. ``backend``: ``"auto"``
    (Embree when installed), ``"embree"`` or ``"pybullet"``.
    """
    if backend not in ("auto", "embree", "pybullet"):
        raise TactileBenchError(f"raycast_heights: unknown backend {backend!r}")
    if backend == "embree" or (backend == "auto" and embree_available()):
        return _raycast_embree(meshes, xs, ys, z_from, z_to, miss)
    import pybullet as p  # imported lazily: it prints a build line on import

    num_threads = num_threads or os.cpu_count() or 1
    gx, gy = np.meshgrid(xs, ys)
    n = gx.size
    starts = np.column_stack([gx.ravel(), gy.ravel(), np.full(n, z_from)])
    ends = starts.copy()
    ends[:, 2] = z_to
    # pybullet 3.2.7 answers a batch of exactly MAX_RAY_INTERSECTION_BATCH_SIZE rays with one
    # result too few (the last ray is silently dropped), so stay one below the limit.
    step = p.MAX_RAY_INTERSECTION_BATCH_SIZE - 1
    chunks = [
        (k, starts[k : k + step].tolist(), ends[k : k + step].tolist()) for k in range(0, n, step)
    ]
    out = np.full((len(meshes), n), miss, dtype=np.float64)
    cid = p.connect(p.DIRECT)
    if cid < 0:
        raise TactileBenchError("pybullet: could not open a DIRECT client")
    try:
        for m, (vertices, faces) in enumerate(meshes):
            shape = p.createCollisionShape(
                p.GEOM_MESH,
                vertices=np.asarray(vertices, dtype=np.float64).tolist(),
                indices=np.asarray(faces, dtype=np.int64).ravel().tolist(),
                flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=cid,
            )
            p.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape, physicsClientId=cid)
            for k, chunk_from, chunk_to in chunks:
                hits = p.rayTestBatch(
                    chunk_from, chunk_to, numThreads=num_threads, physicsClientId=cid
                )
                for i, hit in enumerate(hits):
                    if hit[0] >= 0:
                        out[m, k + i] = hit[3][2]
            p.resetSimulation(physicsClientId=cid)  # removeBody fails for static meshes
    finally:
        p.disconnect(physicsClientId=cid)
    return out.reshape(len(meshes), len(ys), len(xs))


def _raycast_embree(
    meshes: Sequence[tuple[np.ndarray, np.ndarray]],
    xs: np.ndarray,
    ys: np.ndarray,
    z_from: float,
    z_to: float,
    miss: float,
) -> np.ndarray:
    """``raycast_heights`` with Embree's robust intersector (float32, meshes centred)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    gx, gy = np.meshgrid(xs, ys)
    length = z_from - z_to
    out = np.full((len(meshes), gx.size), miss, dtype=np.float64)
    for m, (vertices, faces) in enumerate(meshes):
        vertices = np.asarray(vertices, dtype=np.float64)
        centre = (vertices.min(0) + vertices.max(0)) / 2  # float32 keeps ~1e-6 mm near 0
        scene = rtcore_scene.EmbreeScene(robust=True)
        TriangleMesh(
            scene=scene,
            vertices=(vertices - centre).astype(np.float32),
            indices=np.asarray(faces, dtype=np.int32),
        )
        origins = np.stack(
            [gx.ravel() - centre[0], gy.ravel() - centre[1], np.full(gx.size, z_from - centre[2])],
            1,
        ).astype(np.float32)
        dirs = np.zeros_like(origins)
        dirs[:, 2] = -1.0
        limit = np.float32(length)
        dist = scene.run(
            origins, dirs, query="DISTANCE", dists=np.full(gx.size, limit, dtype=np.float32)
        )
        hit = dist < limit
        out[m, hit] = z_from - dist[hit].astype(np.float64)
    return out.reshape(len(meshes), len(ys), len(xs))


def build_bank(
    chars: Sequence[str] = CHARACTERS,
    spec: BrailleSpec | None = None,
    resolution_mm: float = 0.1,
    margin_mm: float = 1.0,
    cache_path: str | os.PathLike | None = None,
) -> HeightFieldBank:
    """Ray-cast the height field of every character (or load it from ``cache_path``).

    The field covers the block plus ``margin_mm`` on every side, so that bilinear sampling
    near the block edges falls off to ``far_mm`` instead of clamping to the top face.
    The grid step is shrunk from ``resolution_mm`` until half the dot spacing is a whole
    number of steps, so every dot apex falls on a grid node and the field's maximum is the
    exact dome height (a 0.1 mm step becomes 0.098 mm: 225 x 225 rays a character).
    A cache whose characters, spec or grid differ is rebuilt, not trusted.
    """
    spec = spec or BrailleSpec()
    chars = tuple(chars)
    if resolution_mm <= 0 or margin_mm <= 0:
        raise TactileBenchError("build_bank: resolution_mm and margin_mm must be positive")
    node = spec.dot_spacing_mm / 2
    res = node / np.ceil(node / resolution_mm - 1e-9)
    half = res * np.ceil((max(spec.block_width_mm, spec.block_depth_mm) / 2 + margin_mm) / res)
    n = int(round(2 * half / res)) + 1
    if cache_path is not None and Path(cache_path).exists():
        try:
            bank = HeightFieldBank.load(cache_path)
        except TactileBenchError:
            bank = None
        if (
            bank is not None
            and bank.chars == chars
            and bank.spec == spec
            and bank.maps.shape[-1] == n
            and abs(bank.half_extent_mm - half) < 1e-9
        ):
            return bank

    coords = np.linspace(-half, half, n)
    top = spec.block_height_mm
    meshes = [braille_mesh(c, spec) for c in chars]
    z = raycast_heights(
        [(m.vertices, m.faces) for m in meshes], coords, coords[::-1],
        z_from=top + spec.dot_height_mm + 1.0, z_to=-1.0, miss=0.0,
    )  # fmt: skip
    bank = HeightFieldBank(
        maps=torch.from_numpy((z - top).astype(np.float32)[:, None]),
        chars=chars,
        half_extent_mm=float(half),
        far_mm=-top,
        spec=spec,
    )
    if cache_path is not None:
        bank.save(cache_path)
    return bank
