"""Signed height of an arbitrary mesh under sensor poses: the depth camera of a sliding DIGIT.

A braille contact is a rigid transform of one height field (``sensor.depth``), but a sensor
sliding over a YCB object sees a different patch of a curved surface every frame, so here we
cast one ray per oversampled pixel, orthographically along the sensor's z axis.

Sensor frame (a pose is the 4 x 4 transform sensor -> object, mm): origin at the centre of the
undeformed gel surface, z along the gel normal pointing INTO the object, x along the gel width
(image columns, left to right), y along the gel height (image rows, top to bottom). This is
the usual camera frame (x right, y down, z forward), so the image reads like the surface seen
through the gel, as in ``sensor.depth`` (whose y axis points up the image: y_here = -y_there).
The signed height of a pixel is ``-z`` of the first surface point its ray meets: positive
where the object penetrates the gel. Rays start ``reach_mm`` behind the gel plane, so a
penetration deeper than that (never physical: the gel is 4.6 mm thick) reads as ``reach_mm``;
pixels whose ray meets nothing within ``reach_mm`` in front of the gel read ``-reach_mm``.

Backends:
- ``embree``: Intel Embree through ``embreex`` (PyPI wheel), a BVH in C++: the fast one.
- ``pybullet``: ``rayTestBatch`` on a static concave mesh; always available (pybullet is a
  dependency) but the ray lists cross into Python, so it is far slower. Used only without
  embreex.
Rays are exact and orthographic, as the DIGIT's depth here is; a rasterising depth camera
(pybullet's TinyRenderer) is perspective and its depth buffer must be linearised.
``embreex``'s ``run`` holds the GIL (two Python threads cast no faster than one), so the
corpus builder (``data.ycb_slide``) puts both cores to work with processes.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import embree_available
from tactile_bench.sensor.timing import timed_span


def _pixel_grid(gel: GelSpec) -> tuple[np.ndarray, np.ndarray]:
    """x (columns, left to right) and y (rows, top to bottom) of the oversampled pixel centres."""
    n = gel.size * gel.oversample
    t = (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5
    ys, xs = np.meshgrid(t * gel.height_mm, t * gel.width_mm, indexing="ij")
    return xs.ravel(), ys.ravel()


def check_poses(poses: np.ndarray | torch.Tensor, name: str = "poses") -> np.ndarray:
    """(N, 4, 4) float64 rigid transforms, or a TactileBenchError naming what is wrong."""
    p = poses.detach().cpu().numpy() if isinstance(poses, torch.Tensor) else np.asarray(poses)
    if p.ndim == 2 and p.shape == (4, 4):
        p = p[None]
    if p.ndim != 3 or p.shape[1:] != (4, 4):
        raise TactileBenchError(f"{name}: expected (N, 4, 4) transforms, got {p.shape}")
    p = p.astype(np.float64)
    if not np.isfinite(p).all():
        raise TactileBenchError(f"{name}: NaN or infinite entries")
    rot = p[:, :3, :3]
    err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max() if len(p) else 0.0
    if err > 1e-3:
        raise TactileBenchError(f"{name}: rotation part is not orthonormal (error {err:.3g})")
    return p


@dataclass
class MeshDepthRenderer:
    """Casts the gel's pixel rays at one mesh; build once per object, render many poses.

    ``vertices`` in mm (object frame), ``faces`` int (F, 3). ``backend`` is ``"embree"``,
    ``"pybullet"`` or ``"auto"`` (embree when installed).
    """

    vertices: np.ndarray
    faces: np.ndarray
    gel: GelSpec = field(default_factory=GelSpec)
    reach_mm: float = 10.0
    backend: str = "auto"
    chunk_frames: int = 64
    _cast: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = field(
        default=None, init=False, repr=False
    )

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.faces = np.asarray(self.faces, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or len(self.vertices) == 0:
            raise TactileBenchError(f"mesh: vertices must be (V, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise TactileBenchError(f"mesh: faces must be (F, 3), got {self.faces.shape}")
        if not np.isfinite(self.vertices).all():
            raise TactileBenchError("mesh: NaN or infinite vertices")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise TactileBenchError("mesh: face indices outside the vertex array")
        if self.reach_mm <= 0:
            raise TactileBenchError(f"mesh_depth: reach_mm must be > 0, got {self.reach_mm}")
        if self.backend == "auto":
            self.backend = "embree" if embree_available() else "pybullet"
        if self.backend == "embree":
            self._cast = self._embree_caster()
        elif self.backend == "pybullet":
            self._cast = self._pybullet_caster()
        else:
            raise TactileBenchError(f"mesh_depth: unknown backend {self.backend!r}")
        self._xs, self._ys = _pixel_grid(self.gel)

    @classmethod
    def from_trimesh(
        cls, mesh: object, gel: GelSpec | None = None, **kw: object
    ) -> MeshDepthRenderer:
        """Renderer of a ``trimesh.Trimesh`` (or anything with ``vertices`` and ``faces``)."""
        return cls(mesh.vertices, mesh.faces, gel or GelSpec(), **kw)  # type: ignore[attr-defined,arg-type]

    # -- backends: each maps (origins (R, 3), unit directions (R, 3)) -> hit distance or inf --
    def _embree_caster(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError as e:
            raise TactileBenchError(
                "mesh_depth: backend 'embree' needs `pip install embreex`"
            ) from e
        # Embree is float32: centre the mesh so mm coordinates keep ~1e-5 mm precision.
        centre = (self.vertices.min(0) + self.vertices.max(0)) / 2
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(
            scene=scene,
            vertices=(self.vertices - centre).astype(np.float32),
            indices=self.faces.astype(np.int32),
        )
        limit = np.float32(2 * self.reach_mm)

        def cast(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
            dist = scene.run(
                (origins - centre).astype(np.float32),
                dirs.astype(np.float32),
                query="DISTANCE",
                dists=np.full(len(origins), limit, dtype=np.float32),
            ).astype(np.float64)
            dist[dist >= limit] = np.inf
            return dist

        scene_ref = scene  # keep the scene alive as long as the closure
        cast.scene = scene_ref  # type: ignore[attr-defined]
        cast.centre = centre  # type: ignore[attr-defined]
        return cast

    def _pybullet_caster(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        import pybullet as p  # imported lazily: it prints a build line on import

        cid = p.connect(p.DIRECT)
        if cid < 0:
            raise TactileBenchError("pybullet: could not open a DIRECT client")
        # vertex lists passed from Python are capped in size: go through a temporary OBJ file
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "mesh.obj")
            with open(path, "w") as handle:
                np.savetxt(handle, self.vertices, fmt="v %.6f %.6f %.6f")
                np.savetxt(handle, self.faces + 1, fmt="f %d %d %d")
            shape = p.createCollisionShape(
                p.GEOM_MESH,
                fileName=path,
                flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=cid,
            )
        p.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape, physicsClientId=cid)
        length = 2 * self.reach_mm
        # a batch of exactly MAX rays silently returns MAX - 1 results (pybullet 3.2.7)
        step = p.MAX_RAY_INTERSECTION_BATCH_SIZE - 1
        threads = os.cpu_count() or 1

        def cast(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
            ends = origins + dirs * length
            out = np.full(len(origins), np.inf)
            for k in range(0, len(origins), step):
                hits = p.rayTestBatch(
                    origins[k : k + step].tolist(),
                    ends[k : k + step].tolist(),
                    numThreads=threads,
                    physicsClientId=cid,
                )
                frac = np.array([h[2] if h[0] >= 0 else np.inf for h in hits])
                out[k : k + step] = frac * length
            return out

        cast.client = cid  # type: ignore[attr-defined]
        return cast

    def close(self) -> None:
        """Release the pybullet client (embree scenes are freed with the object)."""
        cid = getattr(self._cast, "client", None)
        if cid is not None:
            import pybullet as p

            # forget the id first: pybullet reuses ids, a later close must not hit a new client
            self._cast.client = None  # type: ignore[union-attr]
            self._cast = None
            if p.isConnected(physicsClientId=cid):
                p.disconnect(physicsClientId=cid)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown: nothing useful to do
            self.close()

    def render_height(self, poses: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Signed height (N, 1, S*os, S*os) float32 mm, positive inside the gel."""
        with timed_span("height"):
            return self._render_height(poses)

    def _render_height(
        self,
        poses: np.ndarray | torch.Tensor,
        xs: np.ndarray | None = None,
        ys: np.ndarray | None = None,
    ) -> torch.Tensor:
        """Heights of the rays at pixel centres ``xs``, ``ys`` (default: every pixel)."""
        p = check_poses(poses)
        if self._cast is None:
            raise TactileBenchError("mesh_depth: renderer already closed")
        if self.backend == "embree":
            return self._render_embree(p, xs, ys)
        return self.render_rays(p, xs, ys)

    def peak_height(self, poses: np.ndarray | torch.Tensor, step: int = 4) -> np.ndarray:
        """(N,) highest signed height, mm, seen by every ``step``-th pixel in each direction.

        A cheap (1 / step^2 of the rays) estimate of ``render_height(poses)``'s maximum, for
        callers that move a pose before rendering it (``data.ycb_slide.settle_press``): it
        can miss a peak narrower than ``step`` pixels, never overshoots one.
        """
        side = self.gel.size * self.gel.oversample
        keep = np.zeros((side, side), dtype=bool)
        keep[step // 2 :: step, step // 2 :: step] = True
        keep = keep.ravel()
        with timed_span("height.peak"):
            h = self._render_height(poses, self._xs[keep], self._ys[keep])
        return h.flatten(1).amax(1).numpy().astype(np.float64)

    def render_rays(
        self, p: np.ndarray, xs: np.ndarray | None = None, ys: np.ndarray | None = None
    ) -> torch.Tensor:
        """Any backend: float64 ray set-up, then the backend's caster (the reference path)."""
        xs = self._xs if xs is None else xs
        ys = self._ys if ys is None else ys
        n_pix = len(xs)
        out = np.empty((len(p), n_pix), dtype=np.float32)
        local = np.stack([xs, ys, np.full(n_pix, -self.reach_mm)], 1)  # (P, 3)
        for k in range(0, len(p), self.chunk_frames):
            chunk = p[k : k + self.chunk_frames]
            rot, trans = chunk[:, :3, :3], chunk[:, :3, 3]
            # object-frame ray origins: R @ local + t, as one BLAS matmul per chunk
            origins = np.matmul(local[None], rot.transpose(0, 2, 1)) + trans[:, None, :]
            dirs = np.repeat(rot[:, :, 2], n_pix, axis=0)
            with timed_span("height.rays"):
                dist = self._cast(origins.reshape(-1, 3), dirs)
            height = self.reach_mm - dist  # z_hit = dist - reach; height = -z_hit
            height[~np.isfinite(height)] = -self.reach_mm
            out[k : k + len(chunk)] = height.reshape(len(chunk), n_pix)
        return _as_images(out)

    def _render_embree(
        self, p: np.ndarray, xs64: np.ndarray | None = None, ys64: np.ndarray | None = None
    ) -> torch.Tensor:
        """``render_height`` for Embree, with the ray set-up done in float32 (Embree's own
        precision; the frame's origin is moved to the mesh centre first, in float64).

        A pixel's ray starts at x R[:, 0] + y R[:, 1] + (t - reach R[:, 2]) and runs along
        R[:, 2]: two outer products per coordinate instead of a stacked 3 x 3 matmul (less
        set-up). Same rays as ``render_rays`` to float32 rounding (~1e-6 mm).
        """
        scene, centre = self._cast.scene, self._cast.centre  # type: ignore[union-attr]
        xs64 = self._xs if xs64 is None else xs64
        ys64 = self._ys if ys64 is None else ys64
        n_pix = len(xs64)
        xs, ys = xs64.astype(np.float32), ys64.astype(np.float32)
        reach = np.float32(self.reach_mm)
        limit = np.float32(2 * self.reach_mm)
        out = np.empty((len(p), n_pix), dtype=np.float32)
        for k in range(0, len(p), self.chunk_frames):
            chunk = p[k : k + self.chunk_frames]
            rot = chunk[:, :3, :3]
            base = (chunk[:, :3, 3] - self.reach_mm * rot[:, :, 2] - centre).astype(np.float32)
            r32 = rot.astype(np.float32)
            origins = np.empty((len(chunk), n_pix, 3), dtype=np.float32)
            dirs = np.empty((len(chunk), n_pix, 3), dtype=np.float32)
            for c in range(3):  # coordinate by coordinate: numpy is slow on 3-long inner loops
                row = np.multiply.outer(r32[:, c, 0], xs)
                row += np.multiply.outer(r32[:, c, 1], ys)
                row += base[:, c, None]
                origins[:, :, c] = row
                dirs[:, :, c] = r32[:, c, 2, None]
            with timed_span("height.rays"):
                dist = scene.run(
                    origins.reshape(-1, 3),
                    dirs.reshape(-1, 3),
                    query="DISTANCE",
                    dists=np.full(len(chunk) * n_pix, limit, dtype=np.float32),
                )
            # z_hit = dist - reach, height = -z_hit; a miss within the window reads -reach
            height = np.where(dist < limit, reach - dist, -reach)
            out[k : k + len(chunk)] = height.reshape(len(chunk), n_pix)
        return _as_images(out)


def _as_images(heights: np.ndarray) -> torch.Tensor:
    """(N, P) per-pixel heights as (N, 1, S, S) images (P = S^2), or (N, 1, 1, P) rays."""
    n, n_pix = heights.shape
    side = int(round(n_pix**0.5))
    shape = (n, 1, side, side) if side * side == n_pix else (n, 1, 1, n_pix)
    return torch.from_numpy(heights).reshape(shape)
