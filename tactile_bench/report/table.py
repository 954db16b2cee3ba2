"""The paper's results table, and ours beside it (Markdown and plain text).

Rows of results are dicts: ``row`` (an id of :data:`PAPER_TABLE`, or a new id with optional
``source`` / ``finetune`` labels), ``accuracy``, ``precision``, ``recall`` as fractions in
[0, 1] (what ``classify.train.evaluate`` returns), each a float, a list over seeds, or a
``{"mean": .., "std": ..}`` summary; and an optional ``extra`` dict of notes. A row may
also carry ``second_unit_accuracy`` (the same form) and ``second_unit`` (the unit's name):
the accuracy on the same test contacts rendered by another unit, a column of its own beside
ours, shown when some row has it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PaperRow:
    """One row of Higuera et al. 2023, Table I (classifier tested on 837 real images)."""

    id: str
    source: str
    finetune: str  # % of the real braille set used to fine-tune, "-" if none
    accuracy: float  # percent
    precision: float
    recall: float


PAPER_TABLE: dict[str, PaperRow] = {
    r.id: r
    for r in (
        PaperRow("sim", "Sim", "-", 30.23, 0.34, 0.30),
        PaperRow("sim_ft20", "Sim", "20", 64.99, 0.71, 0.65),
        PaperRow("sim_ft80", "Sim", "80", 73.11, 0.80, 0.73),
        PaperRow("sim_ft100", "Sim", "100", 73.95, 0.81, 0.74),
        PaperRow("sim_aug", "Sim + data aug.", "-", 43.48, 0.61, 0.43),
        PaperRow("sim_aug_ft100", "Sim + data aug.", "100", 73.23, 0.76, 0.73),
        PaperRow("cgan", "cGAN (trained on 100% real)", "-", 31.18, 0.40, 0.31),
        PaperRow("diffusion", "Tactile diffusion (YCB-Slide + 20% real)", "-", 75.74, 0.79, 0.76),
        PaperRow("real", "Real", "-", 100.0, 1.00, 1.00),
    )
}

#: rows of ours that the paper does not have: (training data source, % real fine-tuning)
EXTRA_ROWS: dict[str, tuple[str, str]] = {
    "calibrated": ("Calibrated sim (gap diagnosis fitted on 20% real, no network)", "-"),
    "sim_aug_image": ("Sim + image aug. (kornia, background drawn alike)", "-"),
}

COLUMNS = (
    "training data source",
    "% real fine-tuning",
    "accuracy % (ours)",
    "precision (ours)",
    "recall (ours)",
    "accuracy % on sim, same test contacts (ours)",
    "accuracy % (paper)",
    "precision (paper)",
    "recall (paper)",
    "notes",
)
#: where the second unit's column goes: beside our accuracy
_SECOND_UNIT_AT = COLUMNS.index("accuracy % (ours)") + 1


def summarize(value: Any) -> tuple[float, float, int] | None:
    """(mean, sample std, n) of a float, a list over seeds or a {"mean", "std"} dict."""
    if value is None:
        return None
    if isinstance(value, Mapping):
        std = float(value.get("std", 0.0) or 0.0)
        n = int(value.get("n", 0)) or len(value.get("values", ())) or (2 if std > 0 else 1)
        return float(value["mean"]), std, n
    if isinstance(value, Sequence) and not isinstance(value, str):
        arr = np.asarray(value, dtype=float)
        if arr.size == 0:
            return None
        std = float(arr.std(ddof=1)) if arr.size > 1 else 0.0
        return float(arr.mean()), std, int(arr.size)
    return float(value), 0.0, 1


def _fmt(value: Any, scale: float = 1.0, digits: int = 3) -> str:
    s = summarize(value)
    if s is None or math.isnan(s[0]):
        return "—"
    mean, std, n = s
    text = f"{mean * scale:.{digits}f}"
    return f"{text} ± {std * scale:.{digits}f}" if n > 1 else text


def _fmt_note(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, Mapping) and "mean" in value:
        return _fmt(value)
    if isinstance(value, Sequence) and not isinstance(value, str):
        return ",".join(_fmt_note(v) for v in value)
    return str(value)


def _notes(extra: Mapping[str, Any] | None) -> str:
    if not extra:
        return ""
    return "; ".join(f"{k}={_fmt_note(v)}" for k, v in extra.items() if v is not None)


def second_units(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The names of the second units the rows were tested on (none: no such column)."""
    names = {str(r.get("second_unit")) for r in rows if r.get("second_unit_accuracy") is not None}
    return sorted(names)


def columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """:data:`COLUMNS`, with the second unit's accuracy beside ours when a row has it."""
    out = list(COLUMNS)
    names = second_units(rows)
    if names:
        out.insert(_SECOND_UNIT_AT, f"accuracy % on second unit ({', '.join(names)})")
    return out


def table_cells(rows: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    """One list of cell strings per row: every paper row (in the paper's order, "—" where we
    have no result), followed by rows of ours that the paper does not have; the cells are
    those of ``columns(rows)``."""
    units = second_units(rows)
    by_id: dict[str, Mapping[str, Any]] = {}
    for r in rows:
        by_id[str(r["row"])] = r
    ids = list(PAPER_TABLE) + [i for i in by_id if i not in PAPER_TABLE]
    cells = []
    for rid in ids:
        ours = by_id.get(rid, {})
        paper = PAPER_TABLE.get(rid)
        extra = EXTRA_ROWS.get(rid, (rid, "-"))
        source = str(ours.get("source") or (paper.source if paper else extra[0]))
        finetune = str(ours.get("finetune") or (paper.finetune if paper else extra[1]))
        cells.append(
            [
                source,
                finetune,
                _fmt(ours.get("accuracy"), 100.0, 2),
                _fmt(ours.get("precision"), 1.0, 3),
                _fmt(ours.get("recall"), 1.0, 3),
                _fmt(ours.get("sim_accuracy"), 100.0, 2),
                f"{paper.accuracy:.2f}" if paper else "",
                f"{paper.precision:.2f}" if paper else "",
                f"{paper.recall:.2f}" if paper else "",
                _notes(ours.get("extra")),
            ]
        )
        if units:
            cell = _fmt(ours.get("second_unit_accuracy"), 100.0, 2)
            if len(units) > 1 and ours.get("second_unit_accuracy") is not None:
                cell += f" ({ours.get('second_unit')})"  # the header names several
            cells[-1].insert(_SECOND_UNIT_AT, cell)
    return cells


def results_markdown(rows: Sequence[Mapping[str, Any]], title: str = "Results") -> str:
    """A Markdown section: our numbers (mean ± sample std over seeds) beside the paper's."""
    lines = [f"## {title}", ""]
    header = columns(rows)
    lines.append("| " + " | ".join(header) + " |")
    lines.append("| " + " | ".join("---" for _ in header) + " |")
    for cells in table_cells(rows):
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    lines += [
        "",
        "Accuracy is micro (% of test images), precision and recall are macro averages over "
        "characters; ± is the sample standard deviation over seeds. Paper: Higuera et al. "
        "2023, tested on 837 real DIGIT images. " + _tested_on(rows),
        "",
    ]
    return "\n".join(lines)


def _tested_on(rows: Sequence[Mapping[str, Any]]) -> str:
    """What our test set was: the classify stages record it (``tested_on``)."""
    kinds = {(r.get("extra") or {}).get("tested_on") or "surrogate" for r in rows}
    if kinds == {"real"}:
        return (
            "Ours are tested on the real DIGIT frames of the braille release "
            "(real/color), as the paper's; they have no simulated twin, so there is no sim "
            "column."
        )
    text = (
        "Ours are tested on surrogate-real images of upright, off-grid contacts; the sim "
        "column scores the same classifiers on the same contacts rendered by the simulator, "
        "so its difference to the accuracy column is the sensor's reality gap alone."
    )
    if kinds != {"surrogate"}:
        text += " Rows on real frames have no sim column."
    return text + second_unit_note(rows)


def second_unit_note(rows: Sequence[Mapping[str, Any]]) -> str:
    """A sentence on the second-unit column ("" when the table has none)."""
    units = second_units(rows)
    if not units:
        return ""
    return (
        " The second-unit column scores the same classifiers on the same test contacts "
        f"rendered by another unit ({', '.join(units)}), whose images no translator or "
        "classifier saw before: what a model keeps when it moves between sensor units."
    )


def format_table_for_terminal(
    rows: Sequence[Mapping[str, Any]], title: str = "Results", notes: bool = False
) -> str:
    """The same table as plain aligned text, for printing (notes column optional)."""
    header = columns(rows) if notes else columns(rows)[:-1]
    body = [c if notes else c[:-1] for c in table_cells(rows)]
    widths = [max(len(h), *(len(r[i]) for r in body)) for i, h in enumerate(header)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip()

    rule = "-" * len(line(header))
    return "\n".join([title, rule, line(header), rule, *(line(r) for r in body), rule])
