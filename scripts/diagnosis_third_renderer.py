"""The gap diagnosis on pairs from a third renderer, written apart from both of ours.

    python scripts/diagnosis_third_renderer.py [--cases blur,jpeg] [--variant own|flat|composited]
        [--read-noise 1.5] [--noisy-sim] [--pairs 200] [--seed 0]

``validate-diagnosis`` checks the diagnosis on our surrogate and on ``diagnose.foreign``;
both were written by people who knew the catalogue. This renderer shares no code with
either beyond the depth images: three coloured lights 120 degrees apart with a Phong
specular lobe (not Lambert, not a calibration table), a textured no-contact frame (the
sim's own is off by a colour cast), and sensor noise (read + shot) in **every** real frame,
as a real camera has. Each case plants one effect its own way: a pillbox (disk) defocus
PSF, a gel sag by an exponential kernel, a sub-pixel shift plus a rotation by cubic
interpolation, a polynomial vignetting, Pillow's JPEG at the stored 64 px, per-channel LED
gains, a tone curve. Camera effects act on the no-contact frame too. ``none`` plants
nothing (only the sensor's noise). ``--noisy-sim`` gives the sim frames noise of the same
law too (independent draws), as TACTO adds to its renders. The sim's own no-contact frame
is the real one with a colour cast (``own``), a uniform grey (``flat``, a bare renderer's),
or the sim is composited onto the measured frame (``composited``, TACTO's recipe). Prints
one markdown row per case: what the diagnosis names first, its selection with shrinks and
confusable sets, and the unexplained share.
"""

from __future__ import annotations

import argparse
import io
import time

import numpy as np
import torch
from PIL import Image
from scipy import ndimage

from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.geometry.contacts import classifier_test_protocol
from tactile_bench.sensor.depth import GelSpec, render_depth
from tactile_bench.sensor.heightfield import build_bank

# case: (the catalogue effect it is, None = nothing planted; its parameters)
CASES: dict[str, tuple[str | None, dict[str, float]]] = {
    "none": (None, {}),
    "blur": ("defocus_blur", {"radius_px": 1.5}),
    "elastic": ("elastic_spread", {"length_px": 1.5, "skirt": 0.8}),
    "shift": ("pose_error", {"dx_px": 1.5, "dy_px": -1.0, "rotation_deg": 3.0}),
    "jpeg": ("jpeg", {"quality": 40}),
    "vignetting": ("vignetting", {"k": 0.25}),
    "optics": ("optical_response", {"elevation_shift_deg": -12.0, "specular": 0.5}),
    "gain": ("led_diffusivity", {"gain_r": 1.15, "gain_b": 0.85}),
    "gamma": ("gamma_white_balance", {"gamma": 1.6}),
}
ELEVATION_DEG, SPECULAR, SHININESS = 55.0, 0.25, 20.0


def _pixel_mm(gel: GelSpec) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of every pixel centre from the view centre, mm."""
    dx, dy = gel.mm_per_px
    c = np.arange(gel.size) + 0.5
    return np.meshgrid(c * dx - gel.width_mm / 2, c * dy - gel.height_mm / 2)


def _shade(depth: np.ndarray, gel: GelSpec, elevation: float, specular: float) -> np.ndarray:
    """(N, 3, S, S): red, green and blue lights at azimuths 90, 210, 330 deg, Phong."""
    dx, dy = gel.mm_per_px
    g_row, g_col = np.gradient(depth, dy, dx, axis=(1, 2))
    norm = np.sqrt(1 + g_row**2 + g_col**2)
    normal = np.stack([-g_col / norm, -g_row / norm, 1 / norm], 1)
    out = np.zeros_like(normal)
    el = np.deg2rad(elevation)
    for c, az in enumerate(np.deg2rad([90.0, 210.0, 330.0])):
        light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        half = (light + [0.0, 0.0, 1.0]) / np.linalg.norm(light + [0.0, 0.0, 1.0])
        diffuse = np.clip(np.einsum("nkhw,k->nhw", normal, light), 0, None)
        shine = np.clip(np.einsum("nkhw,k->nhw", normal, half), 0, None) ** SHININESS
        out[:, c] = 150 * diffuse + 255 * specular * shine
    return out


def _no_contact(gel: GelSpec, rng: np.random.Generator) -> np.ndarray:
    """A frame with a radial falloff, colour gradients and a smooth gel texture."""
    x, y = _pixel_mm(gel)
    u, v = x / (gel.width_mm / 2), y / (gel.height_mm / 2)
    frame = np.array([95.0, 110.0, 120.0])[:, None, None] * (1 - 0.12 * (u**2 + v**2))
    frame = frame + np.stack([12 * u, -10 * v, 8 * u * v])
    return frame + ndimage.gaussian_filter(rng.normal(0, 6, frame.shape), (0, 1.2, 1.2))


def _pillbox(radius: float) -> np.ndarray:
    """A disk PSF of ``radius`` px, 8 x 8 supersampled."""
    k = int(np.ceil(radius))
    yy, xx = np.mgrid[-k : k + 1, -k : k + 1].astype(float)
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    w = sum((np.hypot(yy + a, xx + b) <= radius).astype(float) for a in sub for b in sub)
    return w / w.sum()


def _jpeg(frame: np.ndarray, quality: int) -> np.ndarray:
    pixels = np.clip(np.rint(frame), 0, 255).astype(np.uint8).transpose(1, 2, 0)
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="JPEG", quality=quality)
    with Image.open(io.BytesIO(buf.getvalue())) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float64).transpose(2, 0, 1)


def _sag(depth: np.ndarray, length_px: float, skirt: float) -> np.ndarray:
    yy, xx = np.mgrid[-8:9, -8:9]
    kernel = np.exp(-np.hypot(yy, xx) / length_px)
    spread = ndimage.convolve(depth, (kernel / kernel.sum())[None], mode="constant")
    peak = depth.max(axis=(1, 2), keepdims=True)
    spread *= peak / np.maximum(spread.max(axis=(1, 2), keepdims=True), 1e-9)
    return np.maximum(depth, skirt * spread)


def third_renderer_pairs(
    case: str, n: int, seed: int, variant: str, read_noise: float, noisy_sim: bool = False
) -> DiagnosisPairs:
    """``n`` braille contacts: sim by the plain renderer, real with ``case`` planted."""
    _, p = CASES[case]
    bank = build_bank(CHARACTERS, BrailleSpec())
    gel = GelSpec(size=64)
    poses = classifier_test_protocol(bank.chars, n, seed)
    depth_t = render_depth(bank, poses, gel)
    depth = depth_t[:, 0].double().numpy()
    rng = np.random.default_rng([seed, 31])
    frame = _no_contact(gel, rng)
    flat = np.zeros((1, gel.size, gel.size))
    sim_change = _shade(depth, gel, ELEVATION_DEG, SPECULAR) - _shade(
        flat, gel, ELEVATION_DEG, 0.25
    )
    real_depth = depth
    if case == "elastic":
        real_depth = _sag(depth, p["length_px"], p["skirt"])
    if case == "shift":
        real_depth = np.stack(
            [
                ndimage.rotate(
                    ndimage.shift(d, (p["dy_px"], p["dx_px"]), order=3),
                    p["rotation_deg"],
                    reshape=False,
                    order=3,
                )
                for d in depth
            ]
        )
    elevation = ELEVATION_DEG + (p["elevation_shift_deg"] if case == "optics" else 0.0)
    specular = p["specular"] if case == "optics" else SPECULAR
    gain = np.array([p["gain_r"], 1.0, p["gain_b"]]) if case == "gain" else np.ones(3)
    change = _shade(real_depth, gel, elevation, specular) - _shade(flat, gel, elevation, specular)
    light = gain[:, None, None] * frame

    def noise(x: np.ndarray) -> np.ndarray:
        shot = np.sqrt(np.clip(x, 0, None) * 0.02)
        return x + rng.normal(0, read_noise, x.shape) + rng.normal(0, 1, x.shape) * shot

    def camera(x: np.ndarray, noisy: bool) -> np.ndarray:
        if case == "vignetting":
            xm, ym = _pixel_mm(gel)
            r = np.hypot(xm, ym) / np.hypot(gel.width_mm / 2, gel.height_mm / 2)
            x = x * (1 - p["k"] * r**2 - 0.5 * p["k"] * r**4)
        if case == "blur":
            x = ndimage.convolve(x, _pillbox(p["radius_px"])[None, None], mode="nearest")
        if noisy:
            x = noise(x)
        if case == "gamma":
            x = 255 * (np.clip(x, 0, 255) / 255) ** (1 / p["gamma"])
        if case == "jpeg":
            x = np.stack([_jpeg(f, int(p["quality"])) for f in x])
        return np.clip(np.rint(x), 0, 255)

    real = camera(light[None] + gain[None, :, None, None] * change, True)
    measured = camera(light[None], False)[0]  # the averaged no-contact frame
    own = frame + np.array([10.0, -8.0, 5.0])[:, None, None]
    if variant == "flat":
        own = np.full_like(frame, 128.0)
    sim = (measured if variant == "composited" else own)[None] + sim_change
    sim = np.clip(np.rint(noise(sim) if noisy_sim else sim), 0, 255)

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).float()

    return DiagnosisPairs(
        depth=depth_t.float(),
        sim=tensor(sim),
        real=tensor(real),
        background=tensor(measured),
        sim_background=None if variant == "composited" else tensor(np.clip(np.rint(own), 0, 255)),
        labels=[bank.chars[i] for i in poses.labels.tolist()],
        names=[f"contact_{i:04d}" for i in range(n)],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--variant", choices=("own", "flat", "composited"), default="own")
    parser.add_argument("--read-noise", type=float, default=1.5, help="grey levels, every frame")
    parser.add_argument("--noisy-sim", action="store_true", help="the sim frames noisy too")
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    noisy = "real and sim" if args.noisy_sim else "real only"
    print(f"variant {args.variant}, read noise {args.read_noise} ({noisy}), {args.pairs} pairs")
    print(
        "| case | planted | background share | selected (shrink ~ confusable) | first | "
        "unexplained | depth split names | flagged | s |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for case in args.cases.split(","):
        start = time.perf_counter()
        data = third_renderer_pairs(
            case, args.pairs, args.seed, args.variant, args.read_noise, args.noisy_sim
        )
        perm = torch.randperm(args.pairs, generator=torch.Generator().manual_seed(args.seed))
        half = args.pairs // 2
        result = explain_gap(data, perm[:half], perm[half:], seed=args.seed, progress=False)
        first = result.ranking[0] if result.ranking else result.background
        chosen = ", ".join(
            f"{r.effect} ({r.shrink:.3f}"
            + (f" ~ {' / '.join(r.confusable_with)}" if r.confusable_with else "")
            + ")"
            for r in result.ranking
        )
        bg = f"{result.background.shrink:.3f}" if result.background else "-"
        split_first = (result.stability.named_first if result.stability else None) or "-"
        flag = "unstable" if result.unstable else "yes" if result.residual_flagged else "no"
        print(
            f"| {case} | {CASES[case][0] or '-'} | {bg} | {chosen or 'none'} | "
            f"{first.effect if first else '-'} | {result.unexplained:.3f} | {split_first} | "
            f"{flag} | {time.perf_counter() - start:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
