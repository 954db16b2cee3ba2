"""Read a word: classify every frame of the slide, aggregate the frames of each cell.

A frame between two cells shows halves of both and means nothing to a classifier trained
on single cells, so each cell is read only from the frames whose gel centre lies within a
quarter pitch of the cell's centre (the classifier saw offsets of +-3 mm in training; a
quarter of the 14.8 mm pitch is 3.7 mm). Their class log-probabilities are averaged and
renormalised (a geometric mean of the frames' probabilities, i.e. naive Bayes over frames
taken as independent views): one confidently wrong frame pulls the cell down more than
with the arithmetic mean, and agreeing frames sharpen the answer.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from pickle import UnpicklingError
from typing import Any

import numpy as np
import torch
from torch import nn

from tactile_bench.classify.store import load_classifier
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS

AGGREGATION = "mean log-probability of the frames within +-pitch/4 of the cell centre"
FIT_HINT = "run `python -m tactile_bench fit recipes/quick.yaml` (or recipes/table1.yaml) first"


def find_model(run_dir: str | Path, row: str = "diffusion", seed: int = 0) -> Path:
    """``model_seed{seed}.pt`` of the classify stage of table row ``row`` under ``run_dir``.

    A stage directory counts when its ``_done.json`` says kind ``classify`` and config row
    ``row``, or when it is named ``classify_{row}-*`` (the recipes' convention); with
    several (stale configurations), the newest model wins.
    """
    run_dir = Path(run_dir)
    name = f"model_seed{seed}.pt"
    found = set(run_dir.glob(f"classify_{row}-*/{name}"))
    for done in run_dir.glob("*/_done.json"):
        try:
            info = json.loads(done.read_text())
        except (OSError, ValueError):
            continue
        config = info.get("config") or {}
        if info.get("kind") == "classify" and config.get("row") == row:
            found.add(done.parent / name)
    found = {p for p in found if p.is_file()}
    if not found:
        raise TactileBenchError(
            f"{run_dir / f'classify_{row}-*' / name}: no classifier of row {row!r}; "
            f"{FIT_HINT}, or pass --model"
        )
    return max(found, key=lambda p: p.stat().st_mtime)


def load_model(path: str | Path) -> nn.Module:
    """A classifier written by a classify stage (``model_seed{n}.pt``), in eval mode."""
    path = Path(path)
    if not path.is_file():
        raise TactileBenchError(f"{path}: no such model file; {FIT_HINT}, or pass another --model")
    try:
        return load_classifier(path)
    except (
        RuntimeError,
        KeyError,
        TypeError,
        ValueError,
        OSError,
        EOFError,
        UnpicklingError,
    ) as exc:
        text = str(exc).strip().splitlines()
        first = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
        raise TactileBenchError(f"{path}: not a classifier of a classify stage ({first})") from None


@torch.no_grad()
def frame_log_probs(model: nn.Module, foreground: torch.Tensor, batch: int = 128) -> torch.Tensor:
    """(N, C) class log-probabilities of foregrounds (N, 3, S, S), the model in eval mode."""
    was_training = model.training
    model.eval()
    parts = [
        torch.log_softmax(model(foreground[k : k + batch].float()).float(), dim=1)
        for k in range(0, len(foreground), batch)
    ]
    model.train(was_training)
    return torch.cat(parts) if parts else torch.zeros(0, 0)


def cell_frames(x_mm: np.ndarray, cell_x_mm: np.ndarray, pitch_mm: float) -> list[np.ndarray]:
    """Indices of the frames read for each cell: within +-pitch/4 of its centre, or the
    nearest frame when the step leaves none there."""
    x = np.asarray(x_mm, dtype=np.float64)
    if len(x) == 0:
        raise TactileBenchError("read: no frames to read")
    out = []
    for c in np.asarray(cell_x_mm, dtype=np.float64):
        dist = np.abs(x - c)
        idx = np.flatnonzero(dist <= pitch_mm / 4 + 1e-9)
        out.append(idx if len(idx) else np.array([int(dist.argmin())]))
    return out


@dataclass
class CellReading:
    """What was read at one cell of the strip."""

    position: int
    x_mm: float
    true: str
    read: str
    confidence: float
    alternative: str
    alternative_confidence: float
    n_frames: int

    @property
    def correct(self) -> bool:
        return self.read == self.true


def aggregate(
    log_probs: torch.Tensor,
    x_mm: np.ndarray,
    cell_x_mm: np.ndarray,
    pitch_mm: float,
    word: str,
    classes: Sequence[str] | None = None,
) -> list[CellReading]:
    """Per cell: the renormalised mean log-probability of its frames, best and second class."""
    classes = tuple(classes or CHARACTERS[: log_probs.shape[1]])
    if len(classes) != log_probs.shape[1]:
        raise TactileBenchError(f"read: {len(classes)} class names for {log_probs.shape[1]} logits")
    if len(classes) < 2:
        raise TactileBenchError("read: the model must know at least 2 classes")
    readings = []
    for i, idx in enumerate(cell_frames(x_mm, cell_x_mm, pitch_mm)):
        probs = torch.softmax(log_probs[torch.as_tensor(idx)].mean(0), dim=0)
        top = torch.topk(probs, 2)
        readings.append(
            CellReading(
                position=i + 1,
                x_mm=float(cell_x_mm[i]),
                true=word[i],
                read=classes[int(top.indices[0])],
                confidence=float(top.values[0]),
                alternative=classes[int(top.indices[1])],
                alternative_confidence=float(top.values[1]),
                n_frames=len(idx),
            )
        )
    return readings


def summary(
    readings: Sequence[CellReading],
    log_probs: torch.Tensor,
    x_mm: np.ndarray,
    pitch_mm: float,
    classes: Sequence[str],
    settings: dict[str, Any],
) -> dict[str, Any]:
    """The reading as plain types (the ``--json`` output), with the share of single frames
    of the cells' windows that the classifier alone reads right (what aggregating adds)."""
    word = "".join(r.true for r in readings)
    read = "".join(r.read for r in readings)
    correct = sum(r.correct for r in readings)
    probs = log_probs.exp()
    best = probs.max(1)
    cells = np.array([r.x_mm for r in readings])
    groups = cell_frames(x_mm, cells, pitch_mm)
    frame_hits = [
        classes[int(best.indices[k])] == r.true
        for r, idx in zip(readings, groups, strict=True)
        for k in idx
    ]
    return {
        "word": word,
        "read": read,
        "correct": correct,
        "n_cells": len(readings),
        "accuracy": correct / len(readings),
        "frames_read": len(frame_hits),
        "frame_accuracy": sum(frame_hits) / len(frame_hits),
        "aggregation": AGGREGATION,
        "classes": "".join(classes),
        "pitch_mm": pitch_mm,
        **settings,
        "cells": [{**r.__dict__, "correct": r.correct} for r in readings],
        "frames": [
            {"x_mm": round(float(x), 4), "read": classes[int(i)], "confidence": float(p)}
            for x, i, p in zip(x_mm, best.indices, best.values, strict=True)
        ],
    }


def format_reading(result: dict[str, Any]) -> list[str]:
    """Human-readable lines: settings, one line per cell, the word read and the accuracy."""
    lines = [
        f"read {result['word']!r} with {result['model']} ({len(result['classes'])} classes) "
        f"on surrogate {result['profile']!r} frames (seed {result['seed']})",
        f"  {result['n_cells']} cells at {result['pitch_mm']:.2f} mm pitch, press "
        f"{result['press_mm']:g} mm, {len(result['frames'])} frames every {result['step_mm']:g} mm;"
        f" per cell: {AGGREGATION}",
        f"  {'pos':>3}  {'x mm':>6}  true  read  conf   2nd (p)     frames",
    ]
    for c in result["cells"]:
        mark = "" if c["correct"] else "  <- wrong"
        lines.append(
            f"  {c['position']:>3}  {c['x_mm']:6.2f}  {c['true']:<4}  {c['read']:<4}  "
            f"{c['confidence']:.3f}  {c['alternative']} {c['alternative_confidence']:.3f}"
            f"     {c['n_frames']}{mark}"
        )
    unknown = sorted(set(result["word"]) - set(result["classes"]))
    if unknown:
        lines.append(f"  note: the model has no class for {''.join(unknown)}")
    lines.append(
        f"  single frames in the cells' windows read right on their own: "
        f"{100 * result['frame_accuracy']:.1f}% of {result['frames_read']}"
    )
    lines.append(
        f"word read: {result['read']}  (true {result['word']}); characters correct "
        f"{result['correct']}/{result['n_cells']} ({100 * result['accuracy']:.1f}%)"
    )
    return lines
