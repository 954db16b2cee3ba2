"""Report: the paper's table beside ours, and figures that are valid PNG files."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from tactile_bench.report.figures import confusion_png, per_class_bar_png, sample_grid_png
from tactile_bench.report.table import (
    COLUMNS,
    PAPER_TABLE,
    columns,
    format_table_for_terminal,
    results_markdown,
    summarize,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ROW_IDS = ("sim", "sim_ft20", "sim_ft80", "sim_ft100", "sim_aug", "sim_aug_ft100", "cgan")
ROW_IDS += ("diffusion", "real")


def _is_png(path: Path) -> bool:
    data = path.read_bytes()
    return data[:8] == PNG_MAGIC and b"IEND" in data[-16:]


def test_paper_table_rows() -> None:
    assert tuple(PAPER_TABLE) == ROW_IDS
    assert PAPER_TABLE["sim"].accuracy == 30.23
    assert PAPER_TABLE["diffusion"].accuracy == 75.74
    assert PAPER_TABLE["diffusion"].recall == 0.76
    assert PAPER_TABLE["sim_ft20"].finetune == "20"
    assert PAPER_TABLE["real"].precision == 1.0


def test_summarize_forms() -> None:
    assert summarize(0.5) == (0.5, 0.0, 1)
    mean, std, n = summarize([0.2, 0.4])
    assert (mean, n) == (pytest.approx(0.3), 2)
    assert std == pytest.approx(0.1414, abs=1e-4)  # sample std (ddof=1)
    assert summarize({"mean": 0.3, "std": 0.05}) == (0.3, 0.05, 2)
    assert summarize({"mean": 0.3, "std": 0.0}) == (0.3, 0.0, 1)
    assert summarize(None) is None


def test_markdown_has_every_paper_row_and_our_numbers() -> None:
    rows = [
        {"row": "sim", "accuracy": [0.30, 0.32, 0.34], "precision": 0.35, "recall": 0.31},
        {
            "row": "diffusion",
            "accuracy": {"mean": 0.7612, "std": 0.011},
            "precision": {"mean": 0.8, "std": 0.01},
            "recall": {"mean": 0.76, "std": 0.01},
            "extra": {"sim_heldout_accuracy": 0.98765, "seeds": [0, 1, 2], "skip": None},
        },
        {"row": "sim_shadows", "source": "Sim + shadows", "accuracy": 0.5, "precision": 0.5,
         "recall": 0.5},
    ]  # fmt: skip
    md = results_markdown(rows, "Braille table")
    assert md.startswith("## Braille table")
    lines = [line for line in md.splitlines() if line.startswith("|")]
    assert len(lines) == 2 + len(PAPER_TABLE) + 1  # header, rule, paper rows, our extra row
    for row in PAPER_TABLE.values():
        assert any(row.source in line and f"{row.accuracy:.2f}" in line for line in lines)
    assert "32.00 ± 2.00" in md  # mean ± sample std over three seeds, in percent
    assert "76.12 ± 1.10" in md
    assert "0.350" in md and "0.310" in md
    assert "sim_heldout_accuracy=0.988" in md and "seeds=0,1,2" in md
    assert "skip" not in md
    assert "Sim + shadows" in lines[-1]
    sim_ft20 = next(line for line in lines if "| Sim | 20 |" in line)
    assert "—" in sim_ft20  # a paper row we have no result for


def test_terminal_table() -> None:
    text = format_table_for_terminal([{"row": "real", "accuracy": 1.0, "precision": 1.0,
                                       "recall": 1.0}], "T")  # fmt: skip
    lines = text.splitlines()
    assert lines[0] == "T"
    assert "100.00" in text and "Tactile diffusion" in text
    assert len({len(line) for line in lines[1:] if set(line) == {"-"}}) == 1


def test_confusion_and_bar_pngs(tmp_path: Path) -> None:
    classes = [chr(ord("A") + i) for i in range(26)] + ["#"]
    confusion = torch.eye(27, dtype=torch.long) * 30
    confusion[0, 1] = 5
    path = confusion_png(confusion.tolist(), classes, tmp_path / "sub" / "cm.png", "test")
    assert path == tmp_path / "sub" / "cm.png" and _is_png(path)
    per_class = [0.9] * 26 + [None]
    assert _is_png(per_class_bar_png(per_class, classes, tmp_path / "bar.png"))
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["bar.png", "cm.png", "sub"]
    with pytest.raises(ValueError):
        confusion_png([[1, 0], [0, 1]], classes, tmp_path / "bad.png")


def test_sample_grid_png(tmp_path: Path) -> None:
    g = torch.Generator().manual_seed(0)
    columns = {
        "depth": torch.rand(3, 1, 16, 16, generator=g) * 0.8,  # mm, colour-mapped
        "sim": (torch.rand(3, 3, 16, 16, generator=g) * 255).to(torch.uint8),
        "real": torch.rand(3, 3, 16, 16, generator=g) * 255.0,  # float 0..255
        "foreground": 0.5 + 0.1 * torch.randn(3, 3, 16, 16, generator=g),
    }
    path = sample_grid_png(columns, ["A", "B", "C"], tmp_path / "grid.png", "samples")
    assert _is_png(path)
    with pytest.raises(ValueError):
        sample_grid_png({"x": torch.rand(1, 2, 8, 8)}, ["a"], tmp_path / "bad.png")


def test_second_unit_column_beside_ours_only_when_a_row_has_it() -> None:
    rows = [
        {"row": "sim", "accuracy": 0.3, "precision": 0.3, "recall": 0.3},
        {"row": "real", "accuracy": 1.0, "precision": 1.0, "recall": 1.0,
         "second_unit_accuracy": [0.41, 0.45], "second_unit": "digit-b"},
    ]  # fmt: skip
    header = "accuracy % on second unit (digit-b)"
    assert columns(rows[:1]) == list(COLUMNS)  # no row has it: no column
    assert header not in results_markdown(rows[:1])
    assert columns(rows)[COLUMNS.index("accuracy % (ours)") + 1] == header
    md = results_markdown(rows)
    lines = [line.split(" | ") for line in md.splitlines() if line.startswith("|")]
    assert len({len(cells) for cells in lines}) == 1  # every row has the column's cell
    real = next(cells for cells in lines if "100.00" in cells)
    sim = next(cells for cells in lines if cells[0] == "| Sim" and "30.00" in cells)
    assert real[real.index("100.00") + 1] == "43.00 ± 2.83"  # beside ours, mean ± std in %
    assert sim[sim.index("30.00") + 1] == "—"
    assert "another unit (digit-b)" in md
    assert header in format_table_for_terminal(rows)
