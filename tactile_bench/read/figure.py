"""The reading as a figure: the label strip, and the frames at the cell centres with predictions."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from tactile_bench.read.reader import CellReading
from tactile_bench.read.strip import LabelStrip, StripFrames
from tactile_bench.report.figures import save_figure
from tactile_bench.sensor.depth import GelSpec


def strip_figure_png(
    strip: LabelStrip,
    frames: StripFrames,
    readings: Sequence[CellReading],
    path: str | Path,
    title: str = "",
    gel: GelSpec | None = None,
) -> Path:
    """Top: the strip's height field (cell centres, the +-pitch/4 reading windows, the gel's
    footprint at the first cell). Below, per cell, the frame nearest its centre: sim depth,
    surrogate-real image, foreground; titled true -> read (confidence)."""
    n = len(readings)
    fig = Figure(figsize=(max(6.0, 1.6 * n + 0.8), 7.0), layout="constrained")
    grid = fig.add_gridspec(4, n, height_ratios=(1.4, 1, 1, 1))
    ax = fig.add_subplot(grid[0, :])
    x0 = -strip.origin_col * strip.resolution_mm
    x1 = x0 + (strip.heights.shape[1] - 1) * strip.resolution_mm
    ax.imshow(
        strip.heights.numpy(),
        extent=(x0, x1, -strip.half_mm, strip.half_mm),
        cmap="gray",
        interpolation="nearest",
    )
    quarter = strip.pitch_mm / 4
    for r in readings:
        ax.axvspan(r.x_mm - quarter, r.x_mm + quarter, color="tab:orange", alpha=0.2, lw=0)
        ax.axvline(r.x_mm, color="tab:orange", lw=0.8)
    gel = gel or GelSpec()
    gel_w, gel_h = gel.width_mm, gel.height_mm
    ax.add_patch(_rect(readings[0].x_mm - gel_w / 2, -gel_h / 2, gel_w, gel_h))
    ax.set_xlim(frames.x_mm.min() - gel_w / 2, frames.x_mm.max() + gel_w / 2)
    ax.set_xlabel("x (mm)", fontsize=8)
    ax.set_title("orange: each cell's reading window; blue: the gel at the first cell", fontsize=8)
    ax.set_yticks([])
    nearest = [int(np.abs(frames.x_mm - r.x_mm).argmin()) for r in readings]
    foreground = frames.foreground()
    rows: list[tuple[str, Any, dict[str, Any]]] = [
        ("depth", frames.depth[:, 0].numpy(), {"cmap": "viridis"}),
        ("real", frames.images.permute(0, 2, 3, 1).numpy(), {}),
        ("foreground", foreground.clamp(0, 1).permute(0, 2, 3, 1).numpy(), {}),
    ]
    for j, (r, k) in enumerate(zip(readings, nearest, strict=True)):
        for i, (label, arr, kwargs) in enumerate(rows):
            a = fig.add_subplot(grid[i + 1, j])
            a.imshow(arr[k], interpolation="nearest", **kwargs)
            a.set_xticks([])
            a.set_yticks([])
            if j == 0:
                a.set_ylabel(label, fontsize=8)
            if i == 0:
                colour = "black" if r.correct else "tab:red"
                a.set_title(
                    f"{r.true} -> {r.read} ({r.confidence:.2f})\nx {frames.x_mm[k]:.1f} mm",
                    fontsize=8,
                    color=colour,
                )
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def _rect(x: float, y: float, w: float, h: float) -> Rectangle:
    return Rectangle((x, y), w, h, fill=False, edgecolor="tab:blue", lw=1.0)
