"""Figures for the report: confusion matrices, per-class accuracy, sample grids (PNG).

Matplotlib runs on the Agg backend (no display on our machines) through the object API
(``Figure``, not ``pyplot``), so no global figure state leaks between calls. Files are
written atomically: a killed run never leaves a truncated PNG that a cached stage would
later trust.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Render ``fig`` to ``path`` via a temporary file in the same directory + os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    FigureCanvasAgg(fig)
    try:
        fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def confusion_png(
    confusion: Sequence[Sequence[int]] | np.ndarray | torch.Tensor,
    classes: Sequence[str],
    path: str | Path,
    title: str = "Confusion matrix",
) -> Path:
    """Counts heat map (rows: true class, columns: predicted), row-normalised colours."""
    cm = np.asarray(torch.as_tensor(confusion), dtype=float)
    k = cm.shape[0]
    if cm.shape != (k, k) or len(classes) != k:
        raise ValueError(f"confusion {cm.shape} does not match {len(classes)} classes")
    support = cm.sum(axis=1, keepdims=True)
    norm = np.divide(cm, support, out=np.zeros_like(cm), where=support > 0)
    size = max(4.0, 0.32 * k + 1.5)
    fig = Figure(figsize=(size + 1.0, size))
    ax = fig.add_subplot()
    im = ax.imshow(norm, cmap="Blues", vmin=0.0, vmax=1.0)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="fraction of true class")
    ax.set_xticks(range(k), list(classes), fontsize=7)
    ax.set_yticks(range(k), list(classes), fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    acc = np.trace(cm) / max(cm.sum(), 1)
    ax.set_title(f"{title}\n(accuracy {100 * acc:.1f}%, n={int(cm.sum())})", fontsize=9)
    for i in range(k):
        for j in range(k):
            if cm[i, j] > 0:
                colour = "white" if norm[i, j] > 0.5 else "black"
                ax.text(j, i, int(cm[i, j]), ha="center", va="center", fontsize=5, color=colour)
    return save_figure(fig, path)


def per_class_bar_png(
    per_class_accuracy: Sequence[float | None],
    classes: Sequence[str],
    path: str | Path,
    title: str = "Per-class accuracy",
) -> Path:
    """Bar per class (None or NaN: class absent from the test set, drawn as a gap)."""
    if len(per_class_accuracy) != len(classes):
        raise ValueError(f"{len(per_class_accuracy)} accuracies for {len(classes)} classes")
    values = np.array([np.nan if v is None else float(v) for v in per_class_accuracy])
    fig = Figure(figsize=(max(5.0, 0.3 * len(classes) + 1.5), 3.0))
    ax = fig.add_subplot()
    ax.bar(range(len(classes)), np.nan_to_num(values, nan=0.0), color="tab:blue")
    ax.set_xticks(range(len(classes)), list(classes), fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("accuracy")
    present = values[~np.isnan(values)]
    mean = f" (mean {present.mean():.3f})" if present.size else ""
    ax.set_title(title + mean, fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return save_figure(fig, path)


def _to_display(images: torch.Tensor) -> tuple[np.ndarray, dict[str, Any]]:
    """(N, H, W[, 3]) array for imshow and its keyword arguments.

    uint8 or float 0..255 images are scaled to 0..1; float images already in [0, 1]
    (foregrounds, centred on 0.5) are shown as they are; one channel (depth) gets a
    colour map with limits shared by the column so that rows compare.
    """
    x = torch.as_tensor(images).detach().cpu()
    if x.ndim != 4:
        raise ValueError(f"images must be (N, C, S, S), got {tuple(x.shape)}")
    if x.shape[1] == 1:
        arr = x[:, 0].float().numpy()
        finite = arr[np.isfinite(arr)]
        vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        return arr, {"cmap": "viridis", "vmin": vmin, "vmax": max(vmax, vmin + 1e-6)}
    if x.shape[1] != 3:
        raise ValueError(f"images must have 1 or 3 channels, got {x.shape[1]}")
    x = x.float()
    if images.dtype == torch.uint8 or float(x.max()) > 1.5:
        x = x / 255.0
    return x.clamp(0, 1).permute(0, 2, 3, 1).numpy(), {}


def sample_grid_png(
    columns: Mapping[str, torch.Tensor],
    row_labels: Sequence[str],
    path: str | Path,
    title: str = "",
) -> Path:
    """Grid of samples: one column per named kind (depth, sim, real, translated, ...),
    one row per sample (``row_labels``, e.g. the character and pose)."""
    if not columns:
        raise ValueError("no columns to draw")
    shown = {name: _to_display(images) for name, images in columns.items()}
    n_rows = len(row_labels)
    for name, (arr, _) in shown.items():
        if len(arr) < n_rows:
            raise ValueError(f"column {name!r} has {len(arr)} images for {n_rows} rows")
    n_cols = len(shown)
    fig = Figure(figsize=(1.5 * n_cols + 0.6, 1.5 * n_rows + (0.5 if title else 0.2)))
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    for j, (name, (arr, kwargs)) in enumerate(shown.items()):
        for i in range(n_rows):
            ax = axes[i][j]
            ax.imshow(arr[i], interpolation="nearest", **kwargs)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(name, fontsize=9)
            if j == 0:
                ax.set_ylabel(row_labels[i], fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def per_class_heatmap_png(
    matrix: np.ndarray,
    row_labels: Sequence[str],
    classes: Sequence[str],
    path: str | Path,
    title: str = "Per-class accuracy on the real test set",
) -> Path:
    """Rows (e.g. the table's rows) x classes, accuracy in [0, 1]; NaN shows as blank."""
    matrix = np.asarray(matrix, dtype=float)
    fig = Figure(figsize=(0.32 * len(classes) + 2.2, 0.4 * len(row_labels) + 1.2))
    ax = fig.subplots()
    im = ax.imshow(matrix, vmin=0.0, vmax=1.0, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(classes)), list(classes), fontsize=8)
    ax.set_yticks(range(len(row_labels)), list(row_labels), fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.03, pad=0.02)
    fig.tight_layout()
    return save_figure(fig, path)
