"""The paper's 27 braille characters as printed blocks: dot patterns, dimensions, meshes.

Higuera et al. 3D-printed each character (A-Z and the number sign ``#``) as a 2 x 2 x 1 cm
block with one braille cell on top and pressed a DIGIT onto it. We build the same blocks as
watertight triangle meshes so that the sensor layer can ray-cast them into height fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from tactile_bench.errors import TactileBenchError

CHARACTERS: tuple[str, ...] = tuple("ABCDEFGHIJKLMNOPQRSTUVWXYZ#")

# Standard (English, grade 1) braille. Dots 1-2-3 run down the left column, 4-5-6 down the
# right one. ``#`` is the number sign (dots 3-4-5-6).
_PATTERNS = {
    "A": "1", "B": "12", "C": "14", "D": "145", "E": "15", "F": "124", "G": "1245",
    "H": "125", "I": "24", "J": "245", "K": "13", "L": "123", "M": "134", "N": "1345",
    "O": "135", "P": "1234", "Q": "12345", "R": "1235", "S": "234", "T": "2345",
    "U": "136", "V": "1236", "W": "2456", "X": "1346", "Y": "13456", "Z": "1356",
    "#": "3456",
}  # fmt: skip
BRAILLE_DOTS: dict[str, frozenset[int]] = {
    c: frozenset(int(d) for d in dots) for c, dots in _PATTERNS.items()
}


@dataclass(frozen=True)
class BrailleSpec:
    """Dimensions (mm) of a printed braille block.

    The block is the paper's 20 x 20 x 10 mm print. Standard braille (dot spacing 2.3-2.5 mm,
    base diameter 1.4-1.5 mm, height ~0.5 mm) would make a cell only ~4 x 7 mm, a small
    patch of the DIGIT's 18 x 24 mm gel; the paper's prints scale the cell up so that one
    cell fills most of the view. We scale by ~2.3x: 5.5 mm dot spacing (a 2 x 3 cell then spans
    ~8.7 x 14.5 mm, leaving room for the protocols' +-5 mm offsets), 3.4 mm base diameter and
    a 1.1 mm dome (kept lower than a strict 2.3x scale, so that presses of 0.3-0.9 mm touch
    the gel with the dots only, never with the flat top face).

    ``segments_per_side`` and ``cap_rings`` set the mesh resolution: 4 x 12 = 48 segments
    around a dot keep the polygonal cap within ~4 um of the true sphere.
    """

    block_width_mm: float = 20.0
    block_depth_mm: float = 20.0
    block_height_mm: float = 10.0
    dot_spacing_mm: float = 5.5
    dot_base_diameter_mm: float = 3.4
    dot_height_mm: float = 1.1
    segments_per_side: int = 12
    cap_rings: int = 8

    def __post_init__(self) -> None:
        a, s = self.dot_base_diameter_mm / 2, self.dot_spacing_mm
        if not 0 < self.dot_height_mm <= a:
            raise TactileBenchError(
                f"BrailleSpec: dot_height_mm must be in (0, base radius {a}] (a spherical cap)"
            )
        if not a < s / 2:
            raise TactileBenchError("BrailleSpec: dots overlap (base diameter >= spacing)")
        if not (s < self.block_width_mm / 2 and 1.5 * s < self.block_depth_mm / 2):
            raise TactileBenchError("BrailleSpec: the 2 x 3 cell does not fit on the block")
        if self.segments_per_side < 2 or self.cap_rings < 1:
            raise TactileBenchError("BrailleSpec: mesh resolution too coarse")

    @property
    def dot_radius_mm(self) -> float:
        return self.dot_base_diameter_mm / 2

    @property
    def sphere_radius_mm(self) -> float:
        """Radius of the sphere whose cap forms a dot."""
        a, h = self.dot_radius_mm, self.dot_height_mm
        return (a * a + h * h) / (2 * h)


def dot_positions(char: str, spec: BrailleSpec | None = None) -> np.ndarray:
    """Centres (k, 2) in mm of the raised dots of ``char``, in dot-number order.

    The block frame has x to the right and y up (the reading direction seen from above):
    dot 1 is top-left at (-s/2, +s), dot 6 bottom-right at (+s/2, -s).
    """
    spec = spec or BrailleSpec()
    dots = _dots(char)
    s = spec.dot_spacing_mm
    return np.array(
        [[(-0.5 if d <= 3 else 0.5) * s, (1 - (d - 1) % 3) * s] for d in sorted(dots)],
        dtype=np.float64,
    ).reshape(-1, 2)


def _dots(char: str) -> frozenset[int]:
    try:
        return BRAILLE_DOTS[char]
    except (KeyError, TypeError):
        raise TactileBenchError(
            f"unknown braille character {char!r}; known: {''.join(CHARACTERS)}"
        ) from None


def _edge(a: tuple[float, float], b: tuple[float, float], n: int) -> np.ndarray:
    """n points from a (included) towards b (excluded)."""
    t = np.arange(n)[:, None] / n
    return np.asarray(a) + t * (np.asarray(b) - np.asarray(a))


def _rect_ring(x0: float, x1: float, y0: float, y1: float, n: int) -> np.ndarray:
    """Counter-clockwise boundary of a rectangle, n points per side, from (x0, y0)."""
    return np.concatenate(
        [
            _edge((x0, y0), (x1, y0), n),
            _edge((x1, y0), (x1, y1), n),
            _edge((x1, y1), (x0, y1), n),
            _edge((x0, y1), (x0, y0), n),
        ]
    )


class _MeshBuilder:
    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.count = 0

    def add(self, points: np.ndarray) -> np.ndarray:
        idx = np.arange(self.count, self.count + len(points))
        self.vertices.append(np.asarray(points, dtype=np.float64))
        self.count += len(points)
        return idx

    def fan(self, centre: int, ring: np.ndarray, flip: bool = False) -> None:
        nxt = np.roll(ring, -1)
        tri = np.stack([np.full_like(ring, centre), ring, nxt], 1)
        self.faces.append(tri[:, [0, 2, 1]] if flip else tri)

    def strip(self, inner: np.ndarray, outer: np.ndarray) -> None:
        """Quads between two closed rings with matching counts, facing the CCW side."""
        i1, o1 = np.roll(inner, -1), np.roll(outer, -1)
        self.faces.append(np.stack([inner, outer, o1], 1))
        self.faces.append(np.stack([inner, o1, i1], 1))


def braille_mesh(char: str, spec: BrailleSpec | None = None) -> trimesh.Trimesh:
    """Watertight mesh of ``char``'s block: bottom at z = 0, top face at z = block height.

    The top face is tiled on a grid whose cells are centred on the six dot positions, so each
    dot (a spherical cap) sits in its own square tile and all tiles share boundary vertices;
    this avoids a boolean-union dependency while keeping the mesh exact and closed.
    """
    spec = spec or BrailleSpec()
    dots = _dots(char)
    s, n, hz = spec.dot_spacing_mm, spec.segments_per_side, spec.block_height_mm
    w, d = spec.block_width_mm / 2, spec.block_depth_mm / 2
    xs = [-w, -s, 0.0, s, w]
    ys = [-d, -1.5 * s, -0.5 * s, 0.5 * s, 1.5 * s, d]
    raised = {tuple(np.round(p, 9)) for p in dot_positions(char, spec)} if dots else set()

    mb = _MeshBuilder()
    big_r, a, h = spec.sphere_radius_mm, spec.dot_radius_mm, spec.dot_height_mm
    psi_max = np.arcsin(a / big_r) if h < big_r else np.pi / 2
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            ring2 = _rect_ring(xs[i], xs[i + 1], ys[j], ys[j + 1], n)
            ring = mb.add(np.column_stack([ring2, np.full(len(ring2), hz)]))
            cx, cy = (xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2
            if (round(cx, 9), round(cy, 9)) not in raised:
                mb.fan(int(mb.add(np.array([[cx, cy, hz]]))[0]), ring)
                continue
            # Spherical cap: rings from its base circle (r = a, z = top) up to the apex.
            ang = np.arctan2(ring2[:, 1] - cy, ring2[:, 0] - cx)
            outer = ring
            for k in range(spec.cap_rings, 0, -1):
                psi = psi_max * k / spec.cap_rings
                r = big_r * np.sin(psi)
                z = hz + h - big_r * (1 - np.cos(psi))
                pts = np.column_stack(
                    [cx + r * np.cos(ang), cy + r * np.sin(ang), np.full(len(ang), z)]
                )
                inner = mb.add(pts)
                mb.strip(inner, outer)
                outer = inner
            mb.fan(int(mb.add(np.array([[cx, cy, hz + h]]))[0]), outer)

    # Side walls and bottom, along the top face's outer boundary.
    perim = np.concatenate(
        [_edge((xs[i], -d), (xs[i + 1], -d), n) for i in range(len(xs) - 1)]
        + [_edge((w, ys[j]), (w, ys[j + 1]), n) for j in range(len(ys) - 1)]
        + [_edge((xs[i + 1], d), (xs[i], d), n) for i in reversed(range(len(xs) - 1))]
        + [_edge((-w, ys[j + 1]), (-w, ys[j]), n) for j in reversed(range(len(ys) - 1))]
    )
    top = mb.add(np.column_stack([perim, np.full(len(perim), hz)]))
    bottom = mb.add(np.column_stack([perim, np.zeros(len(perim))]))
    mb.strip(top, bottom)
    mb.fan(int(mb.add(np.zeros((1, 3)))[0]), bottom, flip=True)

    mesh = trimesh.Trimesh(np.concatenate(mb.vertices), np.concatenate(mb.faces), process=True)
    mesh.merge_vertices()
    return mesh
