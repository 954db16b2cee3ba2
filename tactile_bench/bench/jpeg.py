"""JPEG codecs side by side: ours, kornia's differentiable one, and libjpeg the reference.

``effects/camera.py`` carries its own differentiable JPEG (``jpeg_approx``: DCT and
quantisation as matrix products, resizes folded in) beside kornia's
``jpeg_codec_differentiable`` (issue 20). Keeping ours is worth it only if it is faster or
closer to the encoder that writes real datasets' files, so this section measures both
against ``libjpeg`` (Pillow's libjpeg, encode and decode) on the same frames: images/s
forward, images/s forward + backward (the two differentiable codecs), and the error of
each output against libjpeg's (mean absolute difference in grey levels 0..255 and PSNR).

Frames are the project's own: the default surrogate DIGIT with its ``jpeg`` effect off
(the frame before the stream compresses it), braille contacts, at the stored 64 x 64 and
at the sensor's native frame (rendered square at the native height, area-averaged to the
native width). Three settings: stored frames coded at the stored size, stored frames coded
at the native size and area-averaged back (what the ``jpeg`` effect does; kornia and
libjpeg get the same bilinear upsampling and area averaging around them), native frames
coded at the native size. Ours and kornia's run in chunks of ``StreamCompression.chunk``
images, as the effect runs ours; libjpeg codes frame by frame on one thread. No peak
memory: the sampler's collection before each of the many short timings would cost more
than the codecs.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence
from importlib.metadata import version
from typing import Any

import torch
import torch.nn.functional as F

from tactile_bench.bench.timing import Timing, measure
from tactile_bench.effects.base import per_sub_batch
from tactile_bench.effects.camera import StreamCompression, jpeg_approx, libjpeg
from tactile_bench.geometry.contacts import finetune_test_protocol
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit

QUALITIES = (30, 60, 90)
CODECS = ("ours", "kornia", "libjpeg")
DIFFERENTIABLE = ("ours", "kornia")
#: braille characters of the frames: one, two and four dots (a small bank: ~0.1 s each)
CHARS = ("A", "K", "X", "#")
#: the codecs' block grid: 8 x 8 DCT blocks on 2 x 2 subsampled chroma
MCU = 16

Codec = Callable[[torch.Tensor, float], torch.Tensor]


def tactile_frames(
    n: int, n_native: int, native_hw: tuple[int, int] = StreamCompression.native_hw, seed: int = 0
) -> dict[str, Any]:
    """Real-looking frames before stream compression: ``n`` at 64 x 64, ``n_native`` at
    ``native_hw``, of the same contacts (surrogate DIGIT, ``jpeg`` off, braille presses)."""
    profile = SurrogateDigit.from_profile("digit")
    real = profile.without("jpeg")
    bank = build_bank(CHARS)
    grid = finetune_test_protocol(CHARS)
    order = torch.randperm(len(grid), generator=torch.Generator().manual_seed(seed))
    poses = grid.index(order[: max(n, n_native)])
    start = time.perf_counter()
    gen = torch.Generator().manual_seed(seed)
    stored = real.render(bank, poses.index(slice(0, n)), real.gel(64), gen)
    h, w = native_hw
    # square renders only: the native frame's longer side, then the shorter area-averaged
    square = real.render(bank, poses.index(slice(0, n_native)), real.gel(max(h, w), 1), gen)
    native = F.adaptive_avg_pool2d(square, (h, w)) if n_native else square[..., :h, :w]
    return {
        "stored": stored,
        "native": native,
        "render_s": time.perf_counter() - start,
        "source": f"surrogate DIGIT (profile {profile.name!r} with its jpeg effect off), braille "
        f"contacts on characters {' '.join(CHARS)} drawn from the fine-tune/test grid "
        f"(seed {seed}); native frames rendered at {max(h, w)} x {max(h, w)} and "
        f"area-averaged to {h} x {w}",
    }


def _ours(coded_hw: tuple[int, int]) -> Codec:
    return lambda x, q: jpeg_approx(x, q, coded_hw)


def _kornia(x: torch.Tensor, q: float) -> torch.Tensor:
    """kornia's codec on 0..255 frames: it takes [0, 1] and one quality per image or one
    for all, shape (1,)."""
    from kornia.enhance import jpeg_codec_differentiable

    return 255.0 * jpeg_codec_differentiable(x / 255.0, torch.tensor([float(q)]))


def _through(codec: Codec, coded_hw: tuple[int, int]) -> Codec:
    """``codec`` at ``coded_hw``: bilinear up, code, area-average back, the same resizes
    ``jpeg_approx`` folds into its matrices."""

    def run(x: torch.Tensor, q: float) -> torch.Tensor:
        if tuple(x.shape[-2:]) == coded_hw:
            return codec(x, q)
        up = F.interpolate(x, size=coded_hw, mode="bilinear", align_corners=False)
        return F.adaptive_avg_pool2d(codec(up, q), tuple(x.shape[-2:]))

    return run


def codecs(coded_hw: tuple[int, int], chunk: int = StreamCompression.chunk) -> dict[str, Codec]:
    """The three codecs on (N, 3, H, W) 0..255, each coding at ``coded_hw``; the two
    differentiable ones in chunks of ``chunk`` images, as the effect runs ours."""

    def chunked(codec: Codec) -> Codec:
        return lambda x, q: per_sub_batch(lambda c: codec(c, q), x, size=chunk)

    return {
        "ours": chunked(_ours(coded_hw)),
        "kornia": chunked(_through(_kornia, coded_hw)),
        "libjpeg": _through(libjpeg, coded_hw),
    }


def errors(out: torch.Tensor, ref: torch.Tensor) -> dict[str, float | None]:
    """Mean and largest absolute difference (grey levels) and PSNR (dB, None if equal)."""
    diff = (out.double() - ref.double()).abs()
    mse = float(diff.square().mean())
    return {
        "mae": float(diff.mean()),
        "max_abs": float(diff.max()),
        "psnr": 10 * math.log10(255.0**2 / mse) if mse > 0 else None,
    }


def _forward_backward(codec: Codec, x: torch.Tensor, q: float) -> Callable[[], None]:
    def run() -> None:
        leaf = x.detach().requires_grad_(True)
        codec(leaf, q).mean().backward()

    return run


def _times(t: Timing) -> dict[str, Any]:
    """The timing without its peak memory (not sampled here, so not a zero to misread)."""
    return {k: v for k, v in t.to_dict().items() if k != "peak_mib"}


def _row(
    name: str, codec: Codec, x: torch.Tensor, q: float, ref: torch.Tensor, repeats: int
) -> dict[str, Any]:
    with torch.no_grad():
        fwd = measure(lambda: codec(x, q), len(x), repeats, memory=False)
        out = codec(x, q)
    fb: Timing | None = None
    if name in DIFFERENTIABLE:
        fb = measure(_forward_backward(codec, x, q), len(x), repeats, memory=False)
    vs_ref, vs_input = errors(out, ref), errors(out, x)
    return {
        "codec": name,
        "images": len(x),
        "images_per_s": fwd.per_s,
        "images_per_cpu_s": fwd.per_cpu_s,
        "fwd_bwd_images_per_s": fb.per_s if fb else None,
        "mae_vs_libjpeg": vs_ref["mae"],
        "max_abs_vs_libjpeg": vs_ref["max_abs"],
        "psnr_vs_libjpeg": vs_ref["psnr"],
        "mae_vs_input": vs_input["mae"],
        "forward": _times(fwd),
        "forward_backward": _times(fb) if fb else None,
    }


def _settings(
    frames: dict[str, Any], native_hw: tuple[int, int]
) -> dict[str, tuple[torch.Tensor, tuple[int, int], str]]:
    """{setting: (input frames, size coded at, what it is)}; empty inputs are left out."""
    stored, native = frames["stored"], frames["native"]
    s_hw = tuple(stored.shape[-2:])
    h, w = native_hw
    out = {
        "stored": (stored, s_hw, f"{s_hw[0]} x {s_hw[1]} frames coded at {s_hw[0]} x {s_hw[1]}"),
        "effect": (
            stored,
            native_hw,
            f"{s_hw[0]} x {s_hw[1]} frames coded at {h} x {w} and area-averaged back "
            "(the jpeg effect's path)",
        ),
        "native": (native, native_hw, f"{h} x {w} frames coded at {h} x {w}"),
    }
    return {k: v for k, v in out.items() if len(v[0])}


def describe_kornia_padding(sizes: Sequence[tuple[int, int]]) -> str:
    """What kornia's multiple-of-16 grid did to the sizes coded here, from the sizes."""
    padded = [
        f"{h} x {w} -> {-(-h // MCU) * MCU} x {-(-w // MCU) * MCU}"
        for h, w in sizes
        if h % MCU or w % MCU
    ]
    listed = ", ".join(f"{h} x {w}" for h, w in sizes)
    if not padded:
        return (
            f"kornia codes multiples of {MCU} (it pads bottom and right by replication, as "
            f"libjpeg pads its blocks, and crops back); every size coded here ({listed}) is "
            "one, so nothing was padded or resized"
        )
    return (
        f"kornia codes multiples of {MCU}: it padded (bottom and right, by replication, as "
        f"libjpeg pads its blocks) {', '.join(padded)} and cropped back"
    )


def summarise(rows: list[dict[str, Any]], setting: str) -> dict[str, Any] | None:
    """Ours against kornia in one setting: median speed ratios over the qualities, mean
    errors against libjpeg; None when either codec is missing."""
    by = {(r["quality"], r["codec"]): r for r in rows if r["setting"] == setting}
    qualities = sorted({q for q, c in by if c == "ours" and (q, "kornia") in by})
    if not qualities:
        return None

    def ratios(key: str) -> list[float]:
        return [by[q, "ours"][key] / by[q, "kornia"][key] for q in qualities]

    def mean(codec: str, key: str) -> float:
        return statistics.fmean(by[q, codec][key] for q in qualities)

    fwd, fb = ratios("images_per_s"), ratios("fwd_bwd_images_per_s")
    lib = [by[q, "libjpeg"]["images_per_s"] for q in qualities if (q, "libjpeg") in by]
    ours = statistics.median(by[q, "ours"]["images_per_s"] for q in qualities)
    return {
        "qualities": qualities,
        "ours_over_kornia_forward": statistics.median(fwd),
        "ours_over_kornia_forward_range": [min(fwd), max(fwd)],
        "ours_over_kornia_forward_backward": statistics.median(fb),
        "ours_over_kornia_forward_backward_range": [min(fb), max(fb)],
        "ours_mae_vs_libjpeg": mean("ours", "mae_vs_libjpeg"),
        "kornia_mae_vs_libjpeg": mean("kornia", "mae_vs_libjpeg"),
        "libjpeg_mae_vs_input": mean("libjpeg", "mae_vs_input") if lib else None,
        "libjpeg_over_ours_forward": statistics.median(lib) / ours if lib else None,
    }


def verdict(s: dict[str, Any]) -> str:
    """One sentence from a ``summarise`` result: speed ratio, errors, and what they say."""
    fwd, fb = s["ours_over_kornia_forward"], s["ours_over_kornia_forward_backward"]
    lo, hi = s["ours_over_kornia_forward_range"]
    mo, mk = s["ours_mae_vs_libjpeg"], s["kornia_mae_vs_libjpeg"]
    qs = ", ".join(str(q) for q in s["qualities"])
    speed = "faster" if min(fwd, fb) > 1 else "slower" if max(fwd, fb) < 1 else "mixed in speed"
    error = "closer to" if mo < mk else "further from" if mo > mk else "as close to"
    text = (
        f"ours runs at {fwd:.1f}x kornia's forward speed ({lo:.1f}-{hi:.1f}x over qualities "
        f"{qs}) and {fb:.1f}x its forward+backward speed, at {mo:.2f} grey levels mean error "
        f"against libjpeg vs kornia's {mk:.2f}: ours is {speed} and {error} libjpeg"
    )
    if s.get("libjpeg_mae_vs_input") is not None:
        text += f" (libjpeg itself moves the frames by {s['libjpeg_mae_vs_input']:.2f})"
    return text + "."


def jpeg_section(
    n: int = 32,
    n_native: int = 8,
    qualities: Sequence[int] = QUALITIES,
    repeats: int = 3,
    seed: int = 0,
    native_hw: tuple[int, int] = StreamCompression.native_hw,
) -> dict[str, Any]:
    """Every codec in every setting at every quality: rates, errors against libjpeg, and a
    verdict per setting computed from them (the headline: ``effect``'s when it ran)."""
    frames = tactile_frames(n, n_native, native_hw, seed)
    settings = _settings(frames, native_hw)
    rows = []
    for key, (x, coded_hw, _) in settings.items():
        run = codecs(coded_hw)
        for q in qualities:
            ref = run["libjpeg"](x, q)
            for name in CODECS:
                row = _row(name, run[name], x, q, ref, repeats)
                rows.append({"setting": key, "quality": q, **row})
    summaries = {key: summarise(rows, key) for key in settings}
    ran = [k for k, s in summaries.items() if s is not None]
    headline = "effect" if "effect" in ran else next(iter(ran), None)
    return {
        "frames": {
            "source": frames["source"],
            "stored": len(frames["stored"]),
            "native": len(frames["native"]),
            "render_s": frames["render_s"],
        },
        "settings": {k: {"coded_hw": list(v[1]), "what": v[2]} for k, v in settings.items()},
        "native_hw": list(native_hw),
        "qualities": list(qualities),
        "repeats": repeats,
        "chunk": StreamCompression.chunk,
        "threads": torch.get_num_threads(),
        "kornia": version("kornia"),
        "kornia_padding": describe_kornia_padding(sorted({v[1] for v in settings.values()})),
        "rows": rows,
        "summary": summaries,
        "headline": headline,
        "verdicts": {k: verdict(s) for k, s in summaries.items() if s is not None},
    }
