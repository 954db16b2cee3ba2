"""A foreign renderer: paired data made without the project's own sensor code.

The gap diagnosis was validated only on pairs rendered by the project's renderer, so a pass
could mean "the diagnosis recognises its own code" rather than "it recognises physics". This
module re-implements the sensor independently (it imports no effect, optics, surrogate or
candidate code) and plants one physical effect in the "real" side, in its own way.

Sim optics (``shading``): ``"lambert"`` is four coloured directional lights with a
wrapped-Lambert law over a smooth illumination field; ``"polycalib"`` is the real DIGIT's
Taxim calibration over the real DIGIT no-contact frame (both read from the shared folder,
never copied). The real sensor is the same renderer with the planted effect plus a camera
applied to the whole frame, background included. Lengths given in pixels are for a 64 px
image and scale with size / 64.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from scipy import ndimage

from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.contacts import classifier_test_protocol
from tactile_bench.sensor.depth import GelSpec, render_depth
from tactile_bench.sensor.heightfield import HeightFieldBank

SHADINGS = ("lambert", "polycalib")
VARIANTS = ("own", "composited")
REF_SIZE = 64  # pixel lengths in plant parameters are for this image size
DEFAULT_REAL_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "real"
POLYCALIB_FILE, BACKGROUND_FILE = "digit_polycalib.npz", "digit_background_240x320.jpg"
CALIB_W, CALIB_H = 240, 320  # the DIGIT image the calibration was measured on (w x h)

# wrapped-Lambert lights: azimuth in the image plane (x right, y down), shared elevation
LIGHT_AZIMUTH_DEG = (45.0, 135.0, 225.0, 315.0)
LIGHT_ELEVATION_DEG = 40.0
LIGHT_COLOURS = np.array([[1.0, 0.85, 0.7], [1.0, 0.2, 0.1], [0.1, 1.0, 0.3], [0.2, 0.3, 1.0]])
LIGHT_INTENSITY = 75.0
WRAP = 0.3
AMBIENT = np.array([32.0, 14.0, 22.0])  # a warm no-contact frame, channels unequal
LIGHT_SIDE, FALLOFF_SCALE = 1.3, 2.0  # lights sit outside the frame; each brightens its side
# per-channel quadratic illumination field 1 + c . (u, v, u^2, v^2, uv), u, v in [-1, 1]
FIELD_QUADRATIC = np.array(
    [
        [0.05, -0.04, -0.08, -0.06, 0.03],
        [-0.03, 0.05, -0.07, -0.09, -0.02],
        [0.02, 0.06, -0.10, -0.05, 0.04],
    ]
)


@dataclass(frozen=True)
class ForeignPlant:
    """One effect planted in the real side; ``expected`` is the catalogue effect it is, or
    None when it is outside the catalogue (the diagnosis should flag, not blame)."""

    name: str
    expected: str | None
    kind: str  # "single" (a catalogue effect) or "out_of_catalogue", as in validate.Case
    draw: Callable[[np.random.Generator], dict[str, float]]
    note: str
    parts: tuple[str, ...] = ()  # the plants applied together (one: itself)
    # the catalogue effects it must be named as, or found confusable with (combined plants)
    named_as: tuple[str, ...] = ()


Range = tuple[float, float] | tuple[float, float, float]


def _ranged(ranges: dict[str, Range]) -> Callable[[np.random.Generator], dict[str, float]]:
    """Independent draws: (low, high) uniform, an integer when both bounds are ints;
    (low, high, centre) is centre +- uniform(low, high), on a random side."""

    def draw(rng: np.random.Generator) -> dict[str, float]:
        out = {}
        for name, (low, high, *centre) in ranges.items():
            whole = isinstance(low, int) and isinstance(high, int)
            v = float(rng.integers(low, high + 1) if whole else rng.uniform(low, high))
            out[name] = centre[0] + float(rng.choice([-1.0, 1.0])) * v if centre else v
        return out

    return draw


_MIX = (0.1, 0.3, 0.0)
# name: (catalogue effect it is, None = outside the catalogue; what it is; realistic ranges)
_TABLE: dict[str, tuple[str | None, str, dict[str, Range]]] = {
    "blur": ("defocus_blur", "Gaussian PSF", {"sigma_px": (0.5, 1.2)}),
    "elastic": ("elastic_spread", "soft gel sag", {"a_mm": (0.2, 0.5), "skirt": (0.6, 0.9)}),
    "shift": ("pose_error", "offset", {"length_px": (1.0, 2.5), "angle_deg": (0.0, 360.0)}),
    "jpeg": ("jpeg", "PIL JPEG of every frame", {"quality": (25, 60)}),
    "vignetting": ("vignetting", "cos^4 falloff", {"corner_loss": (0.15, 0.35)}),
    "optics": (
        "optical_response",
        "lambert: other elevation; polycalib: colour mixing; both saturate",
        {"elevation_shift_deg": (10.0, 20.0, 0.0), "saturation": (40.0, 80.0)}
        | {"mix_rg": _MIX, "mix_gb": _MIX, "mix_br": _MIX},
    ),
    "noise": (
        "camera_noise",
        "Poisson + read",
        {"read_noise": (2.0, 5.0), "shot_gain": (0.05, 0.2)},
    ),
    "gain": ("led_diffusivity", "LED power", {f"gain_{c}": (0.05, 0.25, 1.0) for c in "rgb"}),
    "gamma": (
        "gamma_white_balance",
        "white balance, then a tone curve",
        {"gamma": (1.3, 2.0), "wb_r": (0.03, 0.15, 1.0), "wb_b": (0.03, 0.15, 1.0)},
    ),
    "barrel": (None, "radial lens distortion", {"k1": (0.05, 0.12)}),
    "chromatic": (None, "lateral chromatic aberration", {"lateral": (0.01, 0.02, 0.0)}),
}
FOREIGN_PLANTS: dict[str, ForeignPlant] = {
    name: ForeignPlant(
        name, exp, "single" if exp else "out_of_catalogue", _ranged(r), note, (name,)
    )
    for name, (exp, note, r) in _TABLE.items()
}
#: plants applied together: name -> (parts, what it must be named as or found confusable
#: with, what it is). A lens blur is a blur after the optics, the no-contact frame through
#: the same lens, with the sensor's noise after it.
_COMBINED: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "lens_blur": (("blur", "noise"), ("defocus_blur",), "lens blur, noise after it"),
    "blur_elastic": (
        ("blur", "elastic"),
        ("defocus_blur", "elastic_spread"),
        "lens blur and soft gel sag",
    ),
}
SINGLE_PLANTS, COMBINED_PLANTS = tuple(_TABLE), tuple(_COMBINED)
FOREIGN_PLANTS |= {
    name: ForeignPlant(
        name,
        named_as[0],
        "named_or_confusable",
        _ranged({k: v for part in parts for k, v in _TABLE[part][2].items()}),
        note,
        parts,
        named_as,
    )
    for name, (parts, named_as, note) in _COMBINED.items()
}


# ----------------------------------------------------------------------------- geometry
def _coords_mm(gel: GelSpec) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) in mm of every pixel centre from the view centre (x right, y down)."""
    dx, dy = gel.mm_per_px
    centres = np.arange(gel.size) + 0.5
    return np.meshgrid(centres * dx - gel.width_mm / 2, centres * dy - gel.height_mm / 2)


def _slopes(depth: np.ndarray, gel: GelSpec) -> tuple[np.ndarray, np.ndarray]:
    """d(depth)/d(row), d(depth)/d(col) in mm/mm (central differences)."""
    dx, dy = gel.mm_per_px
    return tuple(np.gradient(depth, dy, dx, axis=(1, 2)))


# ----------------------------------------------------------------------------- sim optics
def _lambert(depth: np.ndarray, gel: GelSpec, elevation_deg: float, gain: np.ndarray) -> np.ndarray:
    """(N, 3, S, S) shading of a depth (N, S, S) lit by the four lights, times the field.

    ``gain`` scales the LED light per channel (not the ambient light)."""
    g_row, g_col = _slopes(depth, gel)
    norm = np.sqrt(1.0 + g_row**2 + g_col**2)  # surface normal (-g_col, -g_row, 1) / norm
    x, y = _coords_mm(gel)
    u, v = x / (gel.width_mm / 2), y / (gel.height_mm / 2)
    el = np.deg2rad(elevation_deg)
    centre_falloff = 1.0 / (1.0 + (LIGHT_SIDE / FALLOFF_SCALE) ** 2)
    lit = np.zeros((depth.shape[0], 3, *depth.shape[1:]))
    for az_deg, colour in zip(LIGHT_AZIMUTH_DEG, LIGHT_COLOURS, strict=True):
        az = np.deg2rad(az_deg)
        lx, ly, lz = np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)
        n_dot_l = (-g_col * lx - g_row * ly + lz) / norm
        wrapped = np.maximum(0.0, (n_dot_l + WRAP) / (1 + WRAP))
        dist = np.hypot(u - LIGHT_SIDE * np.cos(az), v - LIGHT_SIDE * np.sin(az))
        falloff = 1.0 / (1.0 + (dist / FALLOFF_SCALE) ** 2) / centre_falloff
        lit += colour[None, :, None, None] * (wrapped * falloff)[:, None]
    field = 1.0 + np.tensordot(FIELD_QUADRATIC, np.stack([u, v, u * u, v * v, u * v]), 1)
    light = AMBIENT[:, None, None] + gain[:, None, None] * LIGHT_INTENSITY * lit
    return field[None] * light


def _polycalib_change(depth: np.ndarray, gel: GelSpec, coeffs: np.ndarray) -> np.ndarray:
    """(N, 3, S, S) colour change by Taxim's table: coeffs (3, bins, bins, 6).

    As in Taxim, the slope is binned by magnitude atan|grad| in [0, pi/2] and direction
    atan2(dz/drow, dz/dcol) in [-pi, pi], and the polynomial is evaluated at *raw pixel
    indices* (x = column 0..239, y = row 0..319) of the 240 x 320 DIGIT image: our pixel
    centres are mapped there. The flat gel's value is subtracted so no contact = no change.
    """
    bins = coeffs.shape[1]
    g_row, g_col = _slopes(depth, gel)
    mag_bin, dir_bin = 0.5 * np.pi / (bins - 1), 2 * np.pi / (bins - 1)
    i = np.clip(np.arctan(np.hypot(g_row, g_col)) // mag_bin, 0, bins - 1).astype(int)
    j = np.clip((np.arctan2(g_row, g_col) + np.pi) // dir_bin, 0, bins - 1).astype(int)
    xs = (np.arange(gel.size) + 0.5) * CALIB_W / gel.size - 0.5  # our pixel centres there
    ys = (np.arange(gel.size) + 0.5) * CALIB_H / gel.size - 0.5
    xx, yy = np.meshgrid(xs, ys)
    basis = np.stack([xx * xx, yy * yy, xx * yy, xx, yy, np.ones_like(xx)], -1)  # (S, S, 6)
    value = np.concatenate(  # in chunks: the gathered coefficients are 6 x the image
        [
            np.einsum("cnhwk,hwk->nchw", coeffs[:, i[k : k + 64], j[k : k + 64]], basis)
            for k in range(0, len(depth), 64)
        ]
    )
    flat = np.einsum("ck,hwk->chw", coeffs[:, 0, int(np.pi // dir_bin)], basis)  # dir 0 if flat
    return value - flat[None]


def _load_real(real_dir: Path | None, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(coeffs (3, bins, bins, 6), the real DIGIT no-contact frame area-resized to (3, S, S))."""
    folder = Path(real_dir) if real_dir is not None else DEFAULT_REAL_DIR
    if not shared_real_available(folder):
        raise TactileBenchError(
            f"shading 'polycalib': {folder} lacks {POLYCALIB_FILE} or "
            f"{BACKGROUND_FILE} (the shared real DIGIT references)"
        )
    with np.load(folder / POLYCALIB_FILE) as z:
        coeffs = np.stack([z["grad_r"], z["grad_g"], z["grad_b"]]).astype(np.float64)
    with Image.open(folder / BACKGROUND_FILE) as im:
        bg = im.convert("RGB").resize((size, size), Image.Resampling.BOX)
    return coeffs, np.asarray(bg, dtype=np.float64).transpose(2, 0, 1)


def shared_real_available(real_dir: Path | None = None) -> bool:
    """True when the shared real DIGIT references (polycalib shading) can be read."""
    folder = Path(real_dir) if real_dir is not None else DEFAULT_REAL_DIR
    return all((folder / n).is_file() for n in (POLYCALIB_FILE, BACKGROUND_FILE))


# ----------------------------------------------------------------------------- the gel
def _soft_gel(depth: np.ndarray, gel: GelSpec, a_mm: float, skirt: float) -> np.ndarray:
    """A soft gel sags around the indenter: the surface follows the indenter where touched
    and a Boussinesq-like spread (1 + (r/a)^2)^-3/2 of the press, keeping its peak, beyond."""
    dx, dy = gel.mm_per_px
    hx, hy = int(np.ceil(6 * a_mm / dx)), int(np.ceil(6 * a_mm / dy))
    kx, ky = np.meshgrid(np.arange(-hx, hx + 1) * dx, np.arange(-hy, hy + 1) * dy)
    kernel = (1.0 + (kx**2 + ky**2) / a_mm**2) ** -1.5
    spread = ndimage.convolve(depth, (kernel / kernel.sum())[None], mode="constant")
    peak = depth.max(axis=(1, 2), keepdims=True)
    spread = spread * peak / np.maximum(spread.max(axis=(1, 2), keepdims=True), 1e-12)
    return np.maximum(depth, skirt * spread)  # never inside the indenter; a gap beyond


def _scene(
    depth: np.ndarray,
    gel: GelSpec,
    real: tuple[np.ndarray, np.ndarray] | None,
    parts: frozenset[str],
    p: dict[str, float],
) -> tuple[np.ndarray, np.ndarray]:
    """(no-contact frame (3, S, S), colour change (N, 3, S, S)) leaving the gel, before the
    camera; ``real`` holds the polycalib references (None: lambert shading)."""
    scale = gel.size / REF_SIZE
    if "elastic" in parts:
        depth = _soft_gel(depth, gel, p["a_mm"], p["skirt"])
    if "shift" in parts:
        angle = np.deg2rad(p["angle_deg"])
        step = p["length_px"] * scale * np.array([0.0, np.sin(angle), np.cos(angle)])
        depth = ndimage.shift(depth, step, order=1)  # the depth lies off by (dx, dy)
    gain = np.array([p[f"gain_{c}"] for c in "rgb"]) if "gain" in parts else np.ones(3)
    if real is None:
        flat = _lambert(np.zeros((1, gel.size, gel.size)), gel, LIGHT_ELEVATION_DEG, gain)[0]
        el = LIGHT_ELEVATION_DEG + (p["elevation_shift_deg"] if "optics" in parts else 0.0)
        change = _lambert(depth, gel, el, gain) - _lambert(np.zeros_like(depth[:1]), gel, el, gain)
    else:
        coeffs, background = real
        flat = background * gain[:, None, None]
        change = _polycalib_change(depth, gel, coeffs) * gain[None, :, None, None]
        if "optics" in parts:
            mix = np.eye(3)
            mix[0, 1], mix[1, 2], mix[2, 0] = p["mix_rg"], p["mix_gb"], p["mix_br"]
            change = np.einsum("cd,ndhw->nchw", mix, change)
    if "optics" in parts:
        change = p["saturation"] * np.tanh(change / p["saturation"])
    return flat, change


# ----------------------------------------------------------------------------- the camera
def _radial_remap(
    x: np.ndarray, gel: GelSpec, factor: Callable[[int, np.ndarray], np.ndarray]
) -> np.ndarray:
    """Each output pixel of channel c samples the scene at (its offset from the centre) *
    factor(c, r), r = radius / half diagonal in mm (the lens is round in mm, not pixels)."""
    xm, ym = _coords_mm(gel)
    r = np.hypot(xm, ym) / np.hypot(gel.width_mm / 2, gel.height_mm / 2)
    dx, dy = gel.mm_per_px
    out = np.empty_like(x)
    for c in range(3):
        f = factor(c, r)
        rows = (ym * f + gel.height_mm / 2) / dy - 0.5
        cols = (xm * f + gel.width_mm / 2) / dx - 0.5
        for k in range(len(x)):
            out[k, c] = ndimage.map_coordinates(x[k, c], [rows, cols], order=1, mode="nearest")
    return out


def _jpeg(frame: np.ndarray, quality: float) -> np.ndarray:
    """One (3, S, S) frame stored as a JPEG and read back (PIL's encoder, 4:2:0)."""
    pixels = np.clip(np.rint(frame), 0, 255).astype(np.uint8).transpose(1, 2, 0)
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="JPEG", quality=int(quality))
    with Image.open(io.BytesIO(buf.getvalue())) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float64).transpose(2, 0, 1)


def _camera(
    x: np.ndarray,
    gel: GelSpec,
    parts: frozenset[str],
    p: dict[str, float],
    rng: np.random.Generator | None,
) -> np.ndarray:
    """The real camera on whole frames (M, 3, S, S): lens, sensor, processing, storage.
    ``rng`` None = the noise-free average frame."""
    scale = gel.size / REF_SIZE
    if "barrel" in parts:  # barrel: the image is squeezed towards the edges
        x = _radial_remap(x, gel, lambda c, r: 1.0 + p["k1"] * r**2)
    if "chromatic" in parts:  # R magnified by 1 + lateral, B by 1 - lateral
        mag = (1 + p["lateral"], 1.0, 1 - p["lateral"])
        x = _radial_remap(x, gel, lambda c, r: np.full_like(r, 1.0 / mag[c]))
    if "vignetting" in parts:  # natural cos^4 falloff, corner_loss lost at the corner
        xm, ym = _coords_mm(gel)
        corner = np.arccos((1 - p["corner_loss"]) ** 0.25)
        focal = np.hypot(gel.width_mm / 2, gel.height_mm / 2) / np.tan(corner)
        x = x * np.cos(np.arctan(np.hypot(xm, ym) / focal)) ** 4
    if "blur" in parts:
        x = ndimage.gaussian_filter(x, (0, 0, p["sigma_px"] * scale, p["sigma_px"] * scale))
    if "noise" in parts and rng is not None:
        electrons = rng.poisson(np.clip(x, 0, None) / p["shot_gain"])
        x = electrons * p["shot_gain"] + rng.normal(0.0, p["read_noise"], x.shape)
    if "gamma" in parts:
        wb = np.array([p["wb_r"], 1.0, p["wb_b"]])[None, :, None, None]
        x = 255.0 * (np.clip(x * wb, 0, 255) / 255.0) ** (1.0 / p["gamma"])
    if "jpeg" in parts:
        x = np.stack([_jpeg(f, p["quality"]) for f in x])
    return np.clip(x, 0, 255)


# ----------------------------------------------------------------------------- the pairs
def _check(plant: str | None, params: dict[str, float], shading: str, variant: str) -> None:
    """One-line errors for unknown names and missing parameters."""
    for what, name, known in (
        ("foreign plant", plant, [None, *FOREIGN_PLANTS]),
        ("shading", shading, SHADINGS),
        ("variant", variant, VARIANTS),
    ):
        if name not in known:
            names = ", ".join(k for k in known if k is not None)
            raise TactileBenchError(f"unknown {what} {name!r}; known: {names}")
    if plant is not None:
        needed = FOREIGN_PLANTS[plant].draw(np.random.default_rng(0))
        missing = sorted(set(needed) - set(params))
        if missing:
            raise TactileBenchError(f"foreign plant {plant!r}: missing params {missing}")


def foreign_pairs(
    bank: HeightFieldBank,
    plant: str | None,
    params: dict[str, float],
    n: int,
    seed: int,
    size: int = 64,
    shading: str = "lambert",
    variant: str = "own",
    real_dir: Path | None = None,
) -> DiagnosisPairs:
    """``n`` braille contacts (poses as ``validate.planted_pairs``): sim by the foreign
    renderer, real by it with ``plant`` at ``params`` and the real camera (seeded)."""
    _check(plant, params, shading, variant)
    gel = GelSpec(size=size)
    poses = classifier_test_protocol(bank.chars, n, seed)
    depth_t = render_depth(bank, poses, gel)
    depth = depth_t[:, 0].double().numpy()
    real_refs = _load_real(real_dir, size) if shading == "polycalib" else None
    parts = frozenset(FOREIGN_PLANTS[plant].parts) if plant is not None else frozenset()
    sim_flat, sim_change = _scene(depth, gel, real_refs, frozenset(), {})
    flat, change = _scene(depth, gel, real_refs, parts, params)
    rng = np.random.default_rng([seed, 23])
    real = _camera(np.clip(flat + change, 0, 255), gel, parts, params, rng)
    measured = np.rint(_camera(np.clip(flat, 0, 255)[None], gel, parts, params, None)[0])
    base = sim_flat if variant == "own" else measured  # composited: TACTO's real background
    sim = np.rint(np.clip(base + sim_change, 0, 255))

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).float()

    return DiagnosisPairs(
        depth=depth_t.float(),
        sim=tensor(sim),
        real=tensor(np.rint(real)),
        background=tensor(measured),
        sim_background=tensor(np.rint(np.clip(sim_flat, 0, 255))) if variant == "own" else None,
        labels=[bank.chars[i] for i in poses.labels.tolist()],
        names=[f"contact_{i:04d}" for i in range(n)],
    )
