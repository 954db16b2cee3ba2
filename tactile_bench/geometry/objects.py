"""Procedural stand-ins for the ten YCB-Slide objects, in mm, seeded and reproducible.

We cannot ship the YCB scans, and the tactile pretraining only needs what a 18 x 24 mm gel
feels: flat faces and sharp edges (boxes), cylinders with rims and beads (cans, bottles),
a mug's lip and handle, knurled caps and chucks, grip ribs, a baseball's raised seam and
stitches, and small text-like relief (embossed lettering on bottles and tools). Each object
is a union of closed (watertight) parts tessellated finely (~0.7 mm edges) so the relief
survives at the gel's ~0.14 mm oversampled pixel; parts may overlap (the depth renderer only
needs the first surface a ray meets). Overall sizes follow ``YCB_SIZES_MM``.

Object frame: z up, x the longest horizontal side, the bounding box centred at the origin.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
import trimesh

from tactile_bench.errors import TactileBenchError

#: Overall extents (x, y, z) in mm of each stand-in, after the YCB object set (Calli et al.,
#: "Benchmarking in manipulation research", 2015, Table 1, and the released scans). The paper's
#: table gives the drill and the hammer by their grip sections, so those two use the overall
#: extents of the scans (approximate). The mug's x includes the handle.
YCB_SIZES_MM: dict[str, tuple[float, float, float]] = {
    "004_sugar_box": (89.0, 38.0, 175.0),
    "005_tomato_soup_can": (66.0, 66.0, 101.0),
    "006_mustard_bottle": (85.0, 50.0, 175.0),
    "021_bleach_cleanser": (98.0, 65.0, 250.0),
    "025_mug": (117.0, 80.0, 82.0),
    "035_power_drill": (184.0, 57.0, 187.0),
    "037_scissors": (200.0, 87.0, 14.0),
    "042_adjustable_wrench": (205.0, 55.0, 10.0),
    "048_hammer": (330.0, 130.0, 33.0),
    "055_baseball": (75.0, 75.0, 75.0),
}

STEP_MM = 0.7  # target edge length of the tessellation

# 3 x 5 bitmaps: enough variety for "text-like" strokes (digits and a few capitals)
_GLYPHS = np.array(
    [
        [[1, 1, 1], [1, 0, 1], [1, 0, 1], [1, 0, 1], [1, 1, 1]],
        [[0, 1, 0], [1, 1, 0], [0, 1, 0], [0, 1, 0], [1, 1, 1]],
        [[1, 1, 1], [0, 0, 1], [1, 1, 1], [1, 0, 0], [1, 1, 1]],
        [[1, 1, 1], [0, 0, 1], [0, 1, 1], [0, 0, 1], [1, 1, 1]],
        [[1, 0, 1], [1, 0, 1], [1, 1, 1], [0, 0, 1], [0, 0, 1]],
        [[1, 1, 1], [1, 0, 0], [1, 1, 1], [0, 0, 1], [1, 1, 1]],
        [[1, 1, 0], [1, 0, 1], [1, 1, 0], [1, 0, 1], [1, 1, 0]],
        [[1, 1, 1], [1, 0, 0], [1, 1, 0], [1, 0, 0], [1, 1, 1]],
        [[1, 0, 1], [1, 1, 1], [1, 1, 1], [1, 0, 1], [1, 0, 1]],
        [[0, 1, 0], [1, 0, 1], [1, 1, 1], [1, 0, 1], [1, 0, 1]],
    ],
    dtype=bool,
)


# ---------------------------------------------------------------- relief functions (mm)
def glyph_relief(
    u: np.ndarray,
    v: np.ndarray,
    rng: np.random.Generator,
    origin: tuple[float, float],
    n_chars: int,
    n_lines: int = 1,
    char_mm: tuple[float, float] = (2.4, 3.6),
    height_mm: float = 0.3,
) -> np.ndarray:
    """Embossed lettering: rows of random 3 x 5 glyphs whose strokes stand ``height_mm`` proud."""
    cw, ch = char_mm
    text = rng.integers(0, len(_GLYPHS), size=(n_lines, n_chars))
    cu = (u - origin[0]) / cw
    cv = (v - origin[1]) / ch
    col, row = np.floor(cu).astype(int), np.floor(cv).astype(int)
    inside = (col >= 0) & (col < n_chars) & (row >= 0) & (row < n_lines)
    # each character cell: 3 x 5 strokes in its left 75 % / lower 85 % (the rest is spacing)
    fu, fv = (cu - col) / 0.75, (cv - row) / 0.85
    inside &= (fu < 1) & (fv < 1)
    out = np.zeros_like(u, dtype=np.float64)
    idx = np.nonzero(inside)[0]
    if len(idx):
        g = text[row[idx], col[idx]]
        gx = np.clip((fu[idx] * 3).astype(int), 0, 2)
        gy = np.clip(4 - (fv[idx] * 5).astype(int), 0, 4)
        out[idx] = height_mm * _GLYPHS[g, gy, gx]
    return out


def ridges(t: np.ndarray, period_mm: float, height_mm: float, duty: float = 0.5) -> np.ndarray:
    """Square-ish ridges along a coordinate: a rib pattern (grip ribs, knurls, vents)."""
    phase = np.mod(t / period_mm, 1.0)
    return height_mm * (phase < duty)


def bump(t: np.ndarray, centre: float, width_mm: float, height_mm: float) -> np.ndarray:
    """A rounded bead (Gaussian profile) across a coordinate: can beads, seams."""
    return height_mm * np.exp(-0.5 * ((t - centre) / width_mm) ** 2)


# ---------------------------------------------------------------- closed primitives
def grid_box(extents: tuple[float, float, float], step: float = STEP_MM) -> trimesh.Trimesh:
    """A watertight box tessellated as a regular grid on every face (edges ~``step``)."""
    ext = np.asarray(extents, dtype=np.float64)
    counts = np.maximum(2, np.ceil(ext / step).astype(int) + 1)
    lin = [np.linspace(-e / 2, e / 2, c) for e, c in zip(ext, counts, strict=True)]
    parts = []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        ga, gb = np.meshgrid(lin[a], lin[b], indexing="ij")
        na, nb = ga.shape
        ids = np.arange(na * nb).reshape(na, nb)
        q = np.stack([ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]], -1).reshape(-1, 4)
        tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
        for sign in (-1.0, 1.0):
            v = np.zeros((na * nb, 3))
            v[:, a], v[:, b], v[:, axis] = ga.ravel(), gb.ravel(), sign * ext[axis] / 2
            # (a, b, axis) is right-handed for axis 0 and 2 orderings below; flip to face outward
            outward = sign * np.cross(np.eye(3)[a], np.eye(3)[b])[axis] > 0
            parts.append(trimesh.Trimesh(v, tris if outward else tris[:, ::-1], process=False))
    box = trimesh.util.concatenate(parts)
    box.merge_vertices()
    return box


def _signed_volume(mesh: trimesh.Trimesh) -> float:
    """Divergence-theorem volume (trimesh's mass properties are 10x slower on 400k faces)."""
    t = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def _densify(profile: np.ndarray, step: float) -> np.ndarray:
    out = [profile[:1]]
    for p0, p1 in zip(profile[:-1], profile[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(p1 - p0) / step)))
        t = np.linspace(0, 1, n + 1)[1:, None]
        out.append(p0 + t * (p1 - p0))
    return np.concatenate(out)


def lathe(profile_rz: list[tuple[float, float]], step: float = STEP_MM) -> trimesh.Trimesh:
    """Surface of revolution about z of an (r, z) profile that starts and ends on the axis."""
    prof = _densify(np.asarray(profile_rz, dtype=np.float64), step)
    sections = int(np.ceil(2 * np.pi * prof[:, 0].max() / step))
    mesh = trimesh.creation.revolve(prof, sections=sections)
    mesh.merge_vertices()
    if _signed_volume(mesh) < 0:
        mesh.invert()
    return mesh


def tube(
    path: np.ndarray,
    radius: float | tuple[float, float],
    up: np.ndarray | None = None,
    step: float = STEP_MM,
) -> trimesh.Trimesh:
    """A closed tube (elliptical section ``radius`` or (a, b)) swept along a 3-D polyline."""
    a, b = (radius, radius) if np.isscalar(radius) else radius  # type: ignore[misc]
    path = _densify(np.asarray(path, dtype=np.float64), step)
    n_around = max(12, int(np.ceil(2 * np.pi * max(a, b) / step)))
    tang = np.gradient(path, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    side = np.cross(tang, up)
    bad = np.linalg.norm(side, axis=1) < 1e-6
    side[bad] = np.cross(tang[bad], [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    normal = np.cross(side, tang)
    phi = 2 * np.pi * np.arange(n_around) / n_around
    ring = (a * np.cos(phi))[None, :, None] * side[:, None] + (b * np.sin(phi))[
        None, :, None
    ] * normal[:, None]
    verts = (path[:, None] + ring).reshape(-1, 3)
    m = len(path)
    ids = np.arange(m * n_around).reshape(m, n_around)
    nxt = np.roll(ids, -1, axis=1)
    faces = [
        np.stack([ids[:-1], ids[1:], nxt[1:]], -1).reshape(-1, 3),
        np.stack([ids[:-1], nxt[1:], nxt[:-1]], -1).reshape(-1, 3),
    ]
    start, end = len(verts), len(verts) + 1
    verts = np.vstack([verts, path[0], path[-1]])
    faces.append(np.stack([np.full(n_around, start), nxt[0], ids[0]], -1))
    faces.append(np.stack([np.full(n_around, end), ids[-1], nxt[-1]], -1))
    mesh = trimesh.Trimesh(verts, np.concatenate(faces), process=False)
    if _signed_volume(mesh) < 0:
        mesh.invert()
    return mesh


def displace(
    mesh: trimesh.Trimesh, fn: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> trimesh.Trimesh:
    """Move every vertex along its normal by ``fn(vertices, normals)`` mm (keeps it closed)."""
    normals = mesh.vertex_normals.copy()
    offset = fn(mesh.vertices, normals)
    return trimesh.Trimesh(mesh.vertices + normals * offset[:, None], mesh.faces, process=False)


def _place(
    mesh: trimesh.Trimesh,
    rotation: np.ndarray | None = None,
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> trimesh.Trimesh:
    t = np.eye(4)
    if rotation is not None:
        t[:3, :3] = rotation
    t[:3, 3] = translation
    mesh.apply_transform(t)
    return mesh


def _rot(axis: str, deg: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(np.radians(deg), np.eye(3)["xyz".index(axis)])[
        :3, :3
    ]


def _away_from_edges(p: np.ndarray, half: np.ndarray, margin: float) -> np.ndarray:
    """1 on a box face at least ``margin`` from its edges, 0 near edges (keeps edges sharp)."""
    inner = np.abs(p) < (half - margin)
    return (inner.sum(1) >= 2).astype(np.float64)


# ---------------------------------------------------------------- the ten objects
def _sugar_box(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    ext = np.array(YCB_SIZES_MM["004_sugar_box"])
    box = grid_box(tuple(ext))
    half = ext / 2
    flap_w = rng.uniform(10, 16)

    def relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        keep = _away_from_edges(p, half, 1.5)
        front = np.abs(p[:, 1]) > half[1] - 1e-6  # the two big faces (normal +-y)
        h = np.where(front, glyph_relief(p[:, 0], p[:, 2], rng, (-30.0, -20.0), 16, 3), 0.0)
        top = p[:, 2] > half[2] - 1e-6  # glued flap: a raised strip across the top
        h += np.where(top & (np.abs(p[:, 1]) < flap_w / 2), 0.35, 0.0)
        side = np.abs(p[:, 0]) > half[0] - 1e-6  # glued seam along one narrow side
        h += np.where(side & (p[:, 1] > half[1] - 12), 0.3, 0.0)
        return h * keep

    return [displace(box, relief)]


def _can_profile(r: float, h: float) -> list[tuple[float, float]]:
    # bottom centre -> recessed base -> bottom rim -> wall -> top rim -> recessed lid -> axis
    return [
        (0, 3.0),
        (r - 4, 3.0),
        (r - 3, 0.6),
        (r - 1.2, 0.0),
        (r - 0.2, 1.2),
        (r - 1.0, 3.0),
        (r - 1.0, 4.0),
        (r - 0.1, 6.0),
        (r - 0.1, h - 6.0),
        (r - 1.0, h - 4.0),
        (r - 1.0, h - 3.0),
        (r - 0.2, h - 1.2),
        (r - 1.2, h),
        (r - 3, h - 0.6),
        (r - 4, h - 3.5),
        (r - 12, h - 3.5),
        (r - 13, h - 2.8),
        (r - 14, h - 3.5),
        (0, h - 3.5),
    ]


def _tomato_soup_can(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    w, _, h = YCB_SIZES_MM["005_tomato_soup_can"]
    can = lathe(_can_profile(w / 2, h))
    beads = rng.uniform(7.0, 9.0)

    def relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        wall = (np.abs(n[:, 2]) < 0.3) & (p[:, 2] > 12) & (p[:, 2] < h - 12)
        phase = np.mod(p[:, 2] - 12, beads)
        return np.where(wall, -bump(phase, beads / 2, 0.9, 0.6), 0.0)  # rolled-in beads

    return [_place(displace(can, relief), translation=(0, 0, -h / 2))]


def _bottle(
    ext: tuple[float, float, float],
    shoulder: float,
    cap_r: float,
    cap_h: float,
    rng: np.random.Generator,
    grip_ribs: bool,
) -> list[trimesh.Trimesh]:
    w, d, h = ext
    r = w / 2
    body_top = h - cap_h - shoulder
    neck = cap_r * 0.85
    profile = [
        (0, 0.0),
        (r - 6, 0.0),
        (r - 1.5, 0.8),
        (r, 4.0),
        (r, body_top),
        (r * 0.8, body_top + shoulder * 0.55),
        (neck, h - cap_h),
        (0, h - cap_h),
    ]
    body = lathe(profile)
    scale = np.diag([1.0, d / w, 1.0])
    body.apply_transform(np.block([[scale, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
    text_z = rng.uniform(0.35, 0.55) * body_top

    def body_relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        on_wall = (np.abs(n[:, 2]) < 0.2) & (p[:, 2] > 8) & (p[:, 2] < body_top - 4)
        ang = np.arctan2(p[:, 1] * w / d, p[:, 0])
        u = ang * r  # arc length around the (unscaled) body
        front = np.cos(ang) > 0.5
        out = np.where(on_wall & ~front, glyph_relief(u, p[:, 2], rng, (60.0, text_z), 10, 2), 0.0)
        if grip_ribs:
            band = (p[:, 2] > 0.15 * body_top) & (p[:, 2] < 0.45 * body_top) & front
            out += np.where(on_wall & band, -ridges(p[:, 2], 5.0, 0.5, 0.35), 0.0)
        return out

    cap = lathe(
        [(0, h - cap_h - 1.0), (cap_r, h - cap_h - 1.0), (cap_r, h - 1.0), (cap_r - 1.0, h), (0, h)]
    )

    def knurl(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        side = (np.abs(n[:, 2]) < 0.3) & (p[:, 2] < h - 2.5)
        return np.where(side, -ridges(np.arctan2(p[:, 1], p[:, 0]) * cap_r, 1.6, 0.35), 0.0)

    parts = [displace(body, body_relief), displace(cap, knurl)]
    return [_place(m, translation=(0, 0, -h / 2)) for m in parts]


def _mustard_bottle(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    parts = _bottle(YCB_SIZES_MM["006_mustard_bottle"], 30.0, 14.0, 32.0, rng, grip_ribs=False)
    # the flip-top spout: a short cylinder on the cap
    h = YCB_SIZES_MM["006_mustard_bottle"][2]
    spout = lathe([(0, 0.0), (4.0, 0.0), (4.0, 6.0), (0, 6.0)])
    parts.append(_place(spout, _rot("y", 60), (6.0, 0.0, h / 2 - 9.0)))
    return parts


def _bleach_cleanser(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    return _bottle(YCB_SIZES_MM["021_bleach_cleanser"], 55.0, 16.0, 22.0, rng, grip_ribs=True)


def _mug(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    _, d, h = YCB_SIZES_MM["025_mug"]
    r, wall = d / 2, 3.5
    body = lathe(
        [
            (0, 0.0),
            (r - 5, 0.0),
            (r - 1.5, 1.0),
            (r, 5.0),
            (r, h - 1.5),
            (r - wall / 2, h),
            (r - wall, h - 1.5),
            (r - wall, 8.0),
            (r - wall - 3, 6.5),
            (0, 6.5),
        ]
    )
    foot = rng.uniform(0.3, 0.5)

    def relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:  # a glazed foot ring groove
        outer = np.hypot(p[:, 0], p[:, 1]) > r - 0.6
        return np.where(outer, -bump(p[:, 2], 6.5, 0.6, foot), 0.0)

    # C-shaped handle: an elliptical tube from the upper to the lower wall, ends buried in it
    reach = YCB_SIZES_MM["025_mug"][0] - d  # how far the handle sticks out
    t = np.linspace(-np.pi / 2, np.pi / 2, 60)
    tube_b = 5.0
    path = np.stack(
        [r - 3 + (reach - tube_b - 0.0 + 3) * np.cos(t), np.zeros_like(t), h / 2 + 26 * np.sin(t)],
        1,
    )
    handle = tube(path, (tube_b, 7.0), up=np.array([0.0, 1.0, 0.0]))
    parts = [displace(body, relief), handle]
    shift = (-(YCB_SIZES_MM["025_mug"][0] - d) / 2, 0.0, -h / 2)
    return [_place(m, translation=shift) for m in parts]


def _power_drill(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    length, width, height = YCB_SIZES_MM["035_power_drill"]
    r = width / 2
    z_top = height / 2 - r  # axis of the motor housing
    x_back = -length / 2 + 16.5
    housing = tube(
        np.array([[x_back, 0, z_top], [length / 2 - 39, 0, z_top]]), r, up=np.array([0.0, 0.0, 1.0])
    )
    back = lathe([(0, 0.0), (r, 0.0), (r, 6.0), (r - 6, 14.0), (0, 16.0)])
    back = _place(back, _rot("y", -90), (x_back + 0.5, 0, z_top))
    chuck_len = 40.0
    chuck = lathe(
        [(0, 0.0), (16.0, 0.0), (16.0, 24.0), (12.0, 34.0), (6.0, chuck_len), (0, chuck_len)]
    )
    chuck = _place(chuck, _rot("y", 90), (length / 2 - chuck_len, 0, z_top))
    vents = rng.uniform(2.5, 3.5)

    def housing_relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:  # cooling slots
        rear = p[:, 0] < -length / 2 + 75
        upper = n[:, 2] > 0.3
        return np.where(
            rear & upper & (p[:, 0] > -length / 2 + 45), -ridges(p[:, 0], vents, 0.8, 0.4), 0.0
        )

    def chuck_relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:  # knurled sleeve
        side = p[:, 0] < length / 2 - 18
        return np.where(side, -ridges(np.arctan2(p[:, 2] - z_top, p[:, 1]) * 16, 1.8, 0.5), 0.0)

    grip_top, grip_bot = z_top - r + 5, -height / 2 + 28
    handle = tube(
        np.array([[-20.0, 0, grip_top], [-35.0, 0, grip_bot]]),
        (16.0, 24.0),
        up=np.array([0.0, 1.0, 0.0]),
    )

    def grip(p: np.ndarray, n: np.ndarray) -> np.ndarray:  # rubber grip ribs on the back
        back = n[:, 0] < -0.4
        return np.where(back, ridges(p[:, 2], 4.0, 0.6, 0.5), 0.0)

    battery = grid_box((110.0, width, 28.0))

    def label(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        side = (np.abs(n[:, 1]) > 0.9) & (np.abs(p[:, 0]) < 50) & (np.abs(p[:, 2]) < 12)
        return np.where(side, glyph_relief(p[:, 0], p[:, 2], rng, (-30.0, -3.0), 12), 0.0)

    battery = _place(displace(battery, label), translation=(-20.0, 0, -height / 2 + 14))
    return [
        displace(housing, housing_relief),
        back,
        displace(chuck, chuck_relief),
        displace(handle, grip),
        battery,
    ]


def _scissors(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    length, width, thick = YCB_SIZES_MM["037_scissors"]
    ring_minor = thick / 2 - 0.4  # the grip ridges stand 0.4 mm proud
    ring_major = 20.0
    blade_len = length - 2 * (ring_major + ring_minor) + 10
    parts = []
    open_deg = rng.uniform(6.0, 9.0)
    for sign in (-1, 1):
        blade = grid_box((blade_len, 9.0, 2.0))
        blade = _place(
            blade, _rot("z", sign * open_deg), (length / 2 - blade_len / 2, 0, sign * 1.0)
        )
        parts.append(blade)
        ring = trimesh.creation.torus(ring_major, ring_minor, major_sections=180, minor_sections=32)
        cy = sign * (width / 2 - ring_major - ring_minor)
        cx = -length / 2 + ring_major + ring_minor
        ring = _place(ring, translation=(cx, cy, 0.0))

        def grip(p: np.ndarray, n: np.ndarray, cx: float = cx, cy: float = cy) -> np.ndarray:
            return ridges(np.arctan2(p[:, 1] - cy, p[:, 0] - cx) * ring_major, 3.0, 0.4)

        parts.append(displace(ring, grip))
        arm = tube(np.array([[cx + ring_major, cy * 0.6, 0], [0.0, 0, 0]]), (4.0, 3.0))
        parts.append(arm)
    screw = lathe(
        [(0, -thick / 2 + 3), (4.0, -thick / 2 + 3), (4.0, thick / 2 - 3), (0, thick / 2 - 3)]
    )
    parts.append(_place(screw, translation=(0.0, 0, 0)))
    return parts


def _adjustable_wrench(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    length, width, thick = YCB_SIZES_MM["042_adjustable_wrench"]
    head_len = 48.0
    handle = grid_box((length - head_len + 2, 22.0, thick - 2))

    def stamp(p: np.ndarray, n: np.ndarray) -> np.ndarray:  # stamped (engraved) size marking
        face = np.abs(n[:, 2]) > 0.9
        return np.where(
            face, -glyph_relief(p[:, 0], p[:, 1], rng, (-30.0, -2.0), 8, 1, (2.0, 3.0), 0.25), 0.0
        )

    handle = _place(displace(handle, stamp), translation=(-head_len / 2 + 1, 0, 0))
    head = grid_box((head_len, width - 14, thick))
    head = _place(head, translation=(length / 2 - head_len / 2, -7.0, 0))
    jaw_fixed = grid_box((14.0, 14.0, thick))
    jaw_fixed = _place(jaw_fixed, translation=(length / 2 - 7.0, width / 2 - 7.0, 0))
    jaw_move = grid_box((14.0, 12.0, thick - 1))
    gap = rng.uniform(6.0, 12.0)
    jaw_move = _place(jaw_move, translation=(length / 2 - 7.0 - 14.0 - gap, width / 2 - 6.0, 0))
    worm = lathe([(0, 0.0), (4.0, 0.0), (4.0, 14.0), (0, 14.0)])
    worm = displace(
        worm, lambda p, n: np.where(np.abs(n[:, 2]) < 0.3, -ridges(p[:, 2], 1.2, 0.4), 0.0)
    )
    worm = _place(worm, _rot("y", 90), (length / 2 - head_len + 6, -width / 2 + 10, 0))
    return [handle, head, jaw_fixed, jaw_move, worm]


def _hammer(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    length, head_w, thick = YCB_SIZES_MM["048_hammer"]
    head_d = 26.0  # head size along x
    handle = tube(
        np.array([[-length / 2 + 1, 0, 0], [length / 2 - head_d / 2, 0, 0]]),
        (14.0, 12.5),
        up=np.array([0.0, 0.0, 1.0]),
    )

    def grip(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        on_grip = p[:, 0] < -length / 2 + 110
        return np.where(on_grip, -ridges(p[:, 0], 3.5, 0.5, 0.4), 0.0)

    x0 = length / 2 - head_d / 2
    head = grid_box((head_d, 50.0, 24.0))
    head = _place(head, translation=(x0, 0, 0))
    neck = tube(np.array([[x0, 25.0, 0], [x0, 40.0, 0]]), (11.0, 11.0), up=np.array([0.0, 0, 1.0]))
    face = lathe(
        [(0, 0.0), (thick / 2, 0.0), (thick / 2, 20.0), (thick / 2 - 2.5, 25.0), (0, 25.5)]
    )
    face = _place(face, _rot("x", -90), (x0, 40.0, 0))
    face_y_end = 65.5
    claw_len = head_w - face_y_end
    claws = []
    for sign in (-1, 1):
        claw = grid_box((8.0, claw_len, 20.0))
        claws.append(_place(claw, _rot("z", sign * 5.0), (x0 + sign * 6.0, -claw_len / 2, 0)))
    lab = rng.uniform(-20, 0)

    def label(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        on_top = n[:, 2] > 0.9
        return np.where(on_top, glyph_relief(p[:, 0], p[:, 1], rng, (lab - 60, -4.0), 14), 0.0)

    return [displace(handle, lambda p, n: grip(p, n) + label(p, n)), head, neck, face, *claws]


def _seam_curve(n: int = 2000) -> np.ndarray:
    """The baseball (tennis-ball) seam on the unit sphere: two interlocking lobes."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    a, b = 0.75, 0.25
    c = 2 * np.sqrt(a * b)
    pts = np.stack(
        [a * np.cos(t) + b * np.cos(3 * t), a * np.sin(t) - b * np.sin(3 * t), c * np.sin(2 * t)], 1
    )
    return pts / np.linalg.norm(pts, axis=1, keepdims=True)


def _baseball(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    from scipy.spatial import cKDTree

    r = YCB_SIZES_MM["055_baseball"][0] / 2 - 0.6  # stitches stand ~0.6 mm proud
    ball = trimesh.creation.icosphere(subdivisions=7, radius=r)
    rot = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
    seam = _seam_curve() @ rot.T * r
    # 108 double stitches: V-shaped pairs either side of the seam
    n_st = 108
    idx = np.linspace(0, len(seam), n_st, endpoint=False).astype(int)
    tang = np.roll(seam, -1, 0) - np.roll(seam, 1, 0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    side = np.cross(seam / r, tang)
    st = np.concatenate(
        [
            seam[idx] + 2.6 * side[idx] - 0.8 * tang[idx],
            seam[idx] - 2.6 * side[idx] - 0.8 * tang[idx],
            seam[idx] + 1.3 * side[idx],
            seam[idx] - 1.3 * side[idx],
        ]
    )
    seam_tree, st_tree = cKDTree(seam), cKDTree(st)

    def relief(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        d_seam, _ = seam_tree.query(p)
        d_st, _ = st_tree.query(p)
        return -0.5 * np.exp(-0.5 * (d_seam / 0.7) ** 2) + 0.6 * np.exp(-0.5 * (d_st / 0.6) ** 2)

    return [displace(ball, relief)]


#: name -> builder(rng) returning the object's closed parts, in mm.
OBJECTS: dict[str, Callable[[np.random.Generator], list[trimesh.Trimesh]]] = {
    "004_sugar_box": _sugar_box,
    "005_tomato_soup_can": _tomato_soup_can,
    "006_mustard_bottle": _mustard_bottle,
    "021_bleach_cleanser": _bleach_cleanser,
    "025_mug": _mug,
    "035_power_drill": _power_drill,
    "037_scissors": _scissors,
    "042_adjustable_wrench": _adjustable_wrench,
    "048_hammer": _hammer,
    "055_baseball": _baseball,
}


def object_parts(name: str, seed: int = 0) -> list[trimesh.Trimesh]:
    """The closed parts of one stand-in (each watertight), bounding box centred at the origin."""
    if name not in OBJECTS:
        raise TactileBenchError(f"unknown object {name!r}; known: {sorted(OBJECTS)}")
    parts = OBJECTS[name](np.random.default_rng([seed, sorted(OBJECTS).index(name)]))
    lo = np.min([p.bounds[0] for p in parts], axis=0)
    hi = np.max([p.bounds[1] for p in parts], axis=0)
    for p in parts:
        p.apply_translation(-(lo + hi) / 2)
    return parts


@lru_cache(maxsize=4)
def _cached_mesh(name: str, seed: int) -> trimesh.Trimesh:
    return trimesh.util.concatenate(object_parts(name, seed))


def object_mesh(name: str, seed: int = 0) -> trimesh.Trimesh:
    """The stand-in for YCB object ``name`` (e.g. ``"025_mug"``) as one mesh in mm.

    The same (name, seed) always gives the same vertices; the seed moves lettering, rib
    pitches and similar details, not the overall size.
    """
    return _cached_mesh(name, int(seed)).copy()
