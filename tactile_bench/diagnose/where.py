"""Where the gap lies: the squared difference real - sim, split along several axes.

Each axis partitions the total squared error exactly, so its parts' shares sum to 1:

- ``region``: contact patch (depth above ``contact_mm``), rim (a ring ``rim_px`` wide around
  it), free gel (the rest); beside each error share the area share, and their ratio
  (``intensity``: error per unit area relative to the image mean).
- ``band``: radial spatial-frequency bands of the difference image, in cycles per frame
  (Parseval: the bands' powers sum to the spatial squared error). DC is a uniform offset,
  low bands are illumination/background, mid bands contact shape, high bands noise and texture.
- ``channel``: R, G, B.
- ``consistency``: the part that is the same in every pair (the mean difference image: a
  background or vignetting mismatch) versus the part that varies from pair to pair.
- ``depth``: pairs grouped by their maximum contact depth.
- ``label``: pairs grouped by label (when there is more than one).

Vectorised in chunks; reads only the paired images and depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from tactile_bench.diagnose.paired import DiagnosisPairs

CONTACT_MM = 0.01  # 10 um of penetration: below it the gel is taken as untouched
BAND_EDGES = (0.0, 2.0, 4.0, 8.0, 16.0)  # cycles per frame; DC is its own band
CHANNELS = ("R", "G", "B")
REGIONS = ("contact", "rim", "free gel")


@dataclass
class WhereResult:
    """``summary`` is JSON-able (the report's ``where``); ``maps`` are arrays for figures."""

    summary: dict[str, Any]
    maps: dict[str, np.ndarray] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return self.summary


def rim_width_px(size: int) -> int:
    """Rim width: ~1 mm of gel at the default 64 px (4 px), at least 1 px."""
    return max(1, round(size / 16))


def region_masks(depth: torch.Tensor, contact_mm: float, rim_px: int) -> torch.Tensor:
    """(N, 3, S, S) boolean masks: contact patch, rim, free gel (they partition each image)."""
    contact = depth > contact_mm
    grown = F.max_pool2d(contact.float(), 2 * rim_px + 1, stride=1, padding=rim_px) > 0
    rim = grown & ~contact
    return torch.cat([contact, rim, ~grown], 1)


def band_index(
    size_h: int, size_w: int, device: torch.device | str = "cpu"
) -> tuple[torch.Tensor, list[str]]:
    """(H, W) band number of every 2-D FFT frequency on ``device``, and the band names."""
    fy = torch.fft.fftfreq(size_h, device=device) * size_h  # cycles per frame
    fx = torch.fft.fftfreq(size_w, device=device) * size_w
    radius = torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)
    edges = torch.tensor(BAND_EDGES[1:], device=device)
    index = torch.bucketize(radius, edges, right=False) + 1  # (0, 2] -> 1, ...
    index[radius == 0] = 0
    names = ["DC (uniform offset)"]
    lows = BAND_EDGES
    for k in range(1, len(lows)):
        names.append(f"{lows[k - 1]:g}-{lows[k]:g} cyc/frame")
    names.append(f">{lows[-1]:g} cyc/frame")
    return index, names


def _depth_groups(max_depth: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Group pairs by maximum depth: each distinct press (to 0.05 mm) if few, else quartiles."""
    rounded = np.round(max_depth / 0.05) * 0.05
    levels = np.unique(rounded)
    if len(levels) <= 6:
        group = np.searchsorted(levels, rounded)
        names = [f"~{v:.2f} mm" for v in levels]
        return group, names
    edges = np.unique(np.quantile(max_depth, [0.0, 0.25, 0.5, 0.75, 1.0]))
    group = np.clip(np.searchsorted(edges, max_depth, side="right") - 1, 0, len(edges) - 2)
    names = [f"{edges[k]:.2f}-{edges[k + 1]:.2f} mm" for k in range(len(edges) - 1)]
    return group, names


def _parts(
    names: list[str],
    error: np.ndarray,
    amount: np.ndarray | None = None,
    amount_key: str = "area_share",
) -> list[dict[str, Any]]:
    """Parts ranked by their share of the squared error; with ``amount`` (area, frequency
    bins or pairs) also its share and ``intensity`` = error share / amount share (1: even)."""
    total = float(error.sum())
    total_amount = float(amount.sum()) if amount is not None else 0.0
    rows = []
    for k, name in enumerate(names):
        row: dict[str, Any] = {"part": name, "share": float(error[k]) / total if total else 0.0}
        if amount is not None:
            if amount[k] <= 0:  # nothing there (e.g. no contact in any pair): no error either
                continue
            row[amount_key] = float(amount[k]) / total_amount
            row["intensity"] = row["share"] / row[amount_key]
        rows.append(row)
    rows.sort(key=lambda r: r["share"], reverse=True)
    return rows


def _accumulate(
    data: DiagnosisPairs, contact_mm: float, rim_px: int, chunk: int
) -> dict[str, torch.Tensor]:
    """Every sum the axes are split from, in one pass over the pairs, ``chunk`` at a time,
    on the pairs' device."""
    n, _, h, w = data.sim.shape
    device = data.sim.device
    bands, band_names = band_index(h, w, device)
    fy, fx = torch.fft.fftfreq(h, device=device) * h, torch.fft.fftfreq(w, device=device) * w
    radius_k = torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)
    radial_bin = radius_k.round().long().clamp(max=int(math.ceil(radius_k.max())))

    def zeros(*shape: int) -> torch.Tensor:
        return torch.zeros(*shape, dtype=torch.float64, device=device)

    acc = {
        "region_err": zeros(3),
        "region_area": zeros(3),
        "band_err": zeros(len(band_names)),
        "radial": zeros(int(radial_bin.max()) + 1),
        "channel_err": zeros(3),
        "per_pair": zeros(n),
        "sum_abs": zeros(h, w),
        "sum_signed": zeros(3, h, w),
        "contact_freq": zeros(h, w),
        "region_maps": zeros(3, h, w),  # squared error per region
        "max_depth": zeros(n),
    }
    for start in range(0, n, chunk):
        sl = slice(start, start + chunk)
        diff = data.real[sl].float() - data.sim[sl].float()
        sq = diff * diff
        sq_pix = sq.sum(1)  # (B, H, W) summed over channels
        masks = region_masks(data.depth[sl].float(), contact_mm, rim_px)  # (B, 3, H, W)
        mf = masks.double()
        acc["region_err"] += (mf * sq_pix[:, None].double()).sum((0, 2, 3))
        acc["region_area"] += mf.sum((0, 2, 3))
        acc["region_maps"] += (mf * sq_pix[:, None].double()).sum(0)
        power = torch.fft.fft2(diff).abs().square().sum(1).double() / (h * w)  # (B, H, W)
        acc["band_err"] += zeros(len(band_names)).index_add_(
            0, bands.flatten(), power.sum(0).flatten()
        )
        acc["radial"].index_add_(0, radial_bin.flatten(), power.sum(0).flatten())
        acc["channel_err"] += sq.double().sum((0, 2, 3))
        acc["per_pair"][sl] = sq.double().mean((1, 2, 3))
        acc["sum_abs"] += diff.abs().mean(1).double().sum(0)
        acc["sum_signed"] += diff.double().sum(0)
        acc["contact_freq"] += masks[:, 0].double().sum(0)
        acc["max_depth"][sl] = data.depth[sl].flatten(1).amax(1).double()
    return acc


def _axes(data: DiagnosisPairs, acc: dict[str, torch.Tensor]) -> dict[str, Any]:
    """Each axis's parts, largest first (``_parts``), from the sums of ``_accumulate``."""
    n, _, h, w = data.sim.shape
    bands, band_names = band_index(h, w)
    total = float(acc["channel_err"].sum())
    systematic = float((acc["sum_signed"] / n).square().sum()) * n  # sum of ||mean diff||^2
    consistency_err = np.array([systematic, max(total - systematic, 0.0)])
    axes: dict[str, Any] = {}
    axes["region"] = _parts(
        list(REGIONS), acc["region_err"].numpy(), acc["region_area"].numpy(), "area_share"
    )
    bins = np.bincount(bands.flatten().numpy(), minlength=len(band_names)).astype(float)
    axes["band"] = _parts(band_names, acc["band_err"].numpy(), bins, "bin_share")
    axes["channel"] = _parts(list(CHANNELS), acc["channel_err"].numpy())
    axes["consistency"] = _parts(["same in every pair", "varies between pairs"], consistency_err)
    group, depth_names = _depth_groups(acc["max_depth"].numpy())
    pair_err = acc["per_pair"].numpy()
    axes["depth"] = _parts(
        depth_names,
        np.bincount(group, weights=pair_err, minlength=len(depth_names)),
        np.bincount(group, minlength=len(depth_names)).astype(float),
        "pair_share",
    )
    labels = sorted(set(data.labels))
    if len(labels) > 1:
        lab_index = np.array([labels.index(x) for x in data.labels])
        axes["label"] = _parts(
            labels,
            np.bincount(lab_index, weights=pair_err, minlength=len(labels)),
            np.bincount(lab_index, minlength=len(labels)).astype(float),
            "pair_share",
        )
    return axes


def analyse_where(
    data: DiagnosisPairs,
    contact_mm: float = CONTACT_MM,
    rim_px: int | None = None,
    chunk: int = 256,
) -> WhereResult:
    """Split the squared error real - sim along region, band, channel, consistency, depth, label.

    Shares in each axis sum to 1. ``summary["mse"]`` is the mean squared error per pixel
    and channel (0..255 scale); ``maps`` holds the per-pixel error maps for the figures.
    """
    n, _, h, w = data.sim.shape
    rim_px = rim_width_px(w) if rim_px is None else rim_px
    acc = {k: v.cpu() for k, v in _accumulate(data, contact_mm, rim_px, chunk).items()}
    axes = _axes(data, acc)
    summary: dict[str, Any] = {
        "n_pairs": n,
        "size": w,
        "mse": float(acc["channel_err"].sum()) / (n * 3 * h * w),
        "contact_mm": contact_mm,
        "rim_px": rim_px,
        "axes": axes,
    }
    summary["dominant"] = sorted(
        ({"axis": a, **parts[0]} for a, parts in axes.items() if parts),
        key=lambda r: r["share"],
        reverse=True,
    )
    if data.sim_background is not None:
        bg = (data.background.float() - data.sim_background.float()).double()
        summary["background_mse"] = float(bg.square().mean())
    maps = {
        "mean_abs": (acc["sum_abs"] / n).float().numpy(),
        "mean_signed": (acc["sum_signed"] / n).float().numpy(),
        "contact_frequency": (acc["contact_freq"] / n).float().numpy(),
        "region_sq": (acc["region_maps"] / n).float().numpy(),
        "radial_power": (acc["radial"] / (n * 3 * h * w)).float().numpy(),
        "per_pair_mse": acc["per_pair"].numpy().astype(np.float32),
        "max_depth": acc["max_depth"].float().numpy(),
    }
    return WhereResult(summary, maps)
