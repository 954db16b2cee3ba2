"""Reading a word from a braille label strip: geometry, frames, aggregation, the CLI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from tactile_bench.cli import main
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec, dot_positions
from tactile_bench.geometry.contacts import Poses
from tactile_bench.read.reader import aggregate, cell_frames, find_model, frame_log_probs
from tactile_bench.read.strip import (
    CELL_PITCH_RATIO,
    LabelStrip,
    build_strip,
    check_word,
    render_frames,
)
from tactile_bench.sensor.depth import GelSpec, render_depth
from tactile_bench.sensor.heightfield import HeightFieldBank, build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit

WORD = "GA#"
DISTRACTORS = "DBLT"  # G = 1245, D = 145, B = 12, L = 123, T = 2345: near misses


@pytest.fixture(scope="module")
def strip() -> LabelStrip:
    return build_strip(WORD.lower())


@pytest.fixture(scope="module")
def bank() -> HeightFieldBank:
    """Single-character fields of the word and its near misses, from the existing renderer."""
    return build_bank(tuple(WORD + DISTRACTORS))


@pytest.fixture(scope="module")
def sensor() -> SurrogateDigit:
    return SurrogateDigit.from_profile("digit")


def _single_contacts(chars: str, x_mm: float = 0.0, press: float = 0.6) -> Poses:
    n = len(chars)
    return Poses(
        labels=torch.arange(n),
        x_mm=torch.full((n,), x_mm),
        y_mm=torch.zeros(n),
        yaw_deg=torch.zeros(n),
        press_mm=torch.full((n,), press),
    )


def test_check_word_uppercases_and_rejects_unknown_characters() -> None:
    assert check_word("digit") == "DIGIT"
    assert check_word("#A") == "#A"
    for bad, char in (("DIG!T", "'!'"), ("A B", "' '"), ("Ä", "'Ä'")):
        with pytest.raises(TactileBenchError) as info:
            check_word(bad)
        message = str(info.value)
        assert char in message and "ABCDEFGHIJKLMNOPQRSTUVWXYZ#" in message
        assert "\n" not in message
    with pytest.raises(TactileBenchError, match="empty"):
        check_word("")


def test_strip_cells_sit_at_the_pitch_with_their_dots(strip: LabelStrip) -> None:
    spec = BrailleSpec()
    assert strip.word == WORD
    # the standard ratio, rounded to the height field's grid (one step at most)
    assert abs(strip.pitch_mm - CELL_PITCH_RATIO * spec.dot_spacing_mm) <= strip.resolution_mm
    np.testing.assert_allclose(strip.cell_x_mm, np.arange(len(WORD)) * strip.pitch_mm)
    assert strip.dot_height_mm == pytest.approx(spec.dot_height_mm, abs=1e-3)
    # every dot apex of every cell, and nothing else, reaches the dot height
    rows, cols = torch.nonzero(strip.heights > spec.dot_height_mm - 1e-3, as_tuple=True)
    found = np.column_stack(
        [
            (cols.numpy() - strip.origin_col) * strip.resolution_mm,
            strip.half_mm - rows.numpy() * strip.resolution_mm,
        ]
    )
    expected = np.concatenate(
        [dot_positions(c, spec) + [x, 0.0] for c, x in zip(WORD, strip.cell_x_mm, strict=True)]
    )
    assert len(found) == len(expected)
    for point in expected:
        assert np.abs(found - point).max(1).min() < 1e-6
    assert float(strip.heights.min()) == 0.0  # flat plate everywhere else


def test_travel_covers_every_cell_on_the_step_grid(strip: LabelStrip) -> None:
    x = strip.travel_mm(1.0)
    np.testing.assert_allclose(np.diff(x), 1.0)
    assert x[0] >= -strip.pitch_mm / 2 and x[0] - 1.0 < -strip.pitch_mm / 2
    assert x[-1] <= strip.cell_x_mm[-1] + strip.pitch_mm / 2
    assert 0.0 in x
    with pytest.raises(TactileBenchError, match="step"):
        strip.travel_mm(0.0)


def test_frame_at_a_cell_centre_is_that_characters_contact(
    strip: LabelStrip, bank: HeightFieldBank, sensor: SurrogateDigit
) -> None:
    """The depth seen at each cell centre is the existing renderer's single-character contact
    of the same character (and correlates best with it among near-miss characters)."""
    chars = WORD + DISTRACTORS
    gel = GelSpec()
    single = render_depth(bank, _single_contacts(chars), gel).flatten(1)
    frames = render_frames(strip, strip.cell_x_mm, sensor, 0.6, gel)
    seen = frames.depth.flatten(1)
    for i, char in enumerate(WORD):
        assert (seen[i] - single[chars.index(char)]).abs().max() < 1e-4
    a = seen - seen.mean(1, keepdim=True)
    b = single - single.mean(1, keepdim=True)
    corr = (a / a.norm(dim=1, keepdim=True)) @ (b / b.norm(dim=1, keepdim=True)).T
    assert [chars[int(j)] for j in corr.argmax(1)] == list(WORD)
    # the frames are surrogate-real images, not the depth: a background and contact colour
    assert frames.images.dtype == torch.uint8 and frames.images.shape == (3, 3, 64, 64)
    assert (frames.foreground() - 0.5).abs().amax(dim=(1, 2, 3)).min() > 0.05


def test_frame_between_cells_shows_parts_of_both(strip: LabelStrip, sensor: SurrogateDigit) -> None:
    gel = GelSpec()
    frames = render_frames(strip, [strip.pitch_mm / 2], sensor, 0.6, gel)
    depth = frames.depth[0, 0]
    half = depth.shape[1] // 2
    assert depth[:, :half].sum() > 0 and depth[:, half:].sum() > 0  # G's right, A's left dots
    deeper = render_frames(strip, [0.0], sensor, 0.9, gel).depth
    shallower = render_frames(strip, [0.0], sensor, 0.3, gel).depth
    assert deeper.max() > shallower.max()
    with pytest.raises(TactileBenchError, match="press"):
        render_frames(strip, [0.0], sensor, 1.5, gel)


class TemplateReader(nn.Module):
    """Nearest template over x offsets: logits = best correlation with each class's
    foregrounds (a fixed classifier that needs no training)."""

    def __init__(self, templates: torch.Tensor, labels: torch.Tensor, n_classes: int) -> None:
        super().__init__()
        flat = templates.flatten(1) - 0.5
        self.register_buffer("templates", flat / flat.norm(dim=1, keepdim=True))
        self.register_buffer("labels", labels)
        self.n_classes = n_classes

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        flat = x.flatten(1) - 0.5
        corr = (flat / flat.norm(dim=1, keepdim=True)) @ self.templates.T
        logits = torch.full((len(x), self.n_classes), -1.0)
        for c in range(self.n_classes):
            logits[:, c] = corr[:, self.labels == c].amax(1)
        return 20 * logits


def test_reading_the_word_from_surrogate_real_frames(
    strip: LabelStrip, bank: HeightFieldBank, sensor: SurrogateDigit
) -> None:
    chars = WORD + DISTRACTORS
    gel = GelSpec()
    offsets = np.arange(-4, 5) * 1.0
    poses = Poses.cat([_single_contacts(chars, float(x)) for x in offsets])
    gen = torch.Generator().manual_seed(1)
    images = sensor.render(bank, poses, gel, gen).round().clamp(0, 255)
    background = sensor.background(gel).round()
    templates = (images - background) / 255.0 + 0.5
    model = TemplateReader(templates, poses.labels, len(chars)).train()

    x = strip.travel_mm(1.0)
    frames = render_frames(strip, x, sensor, 0.6, gel, torch.Generator().manual_seed(0))
    log_probs = frame_log_probs(model, frames.foreground())
    assert model.training  # restored
    readings = aggregate(log_probs, x, strip.cell_x_mm, strip.pitch_mm, WORD, tuple(chars))
    assert "".join(r.read for r in readings) == WORD
    for r in readings:
        assert r.n_frames >= 7
        assert 0.5 < r.confidence <= 1.0 and r.alternative != r.read
        assert r.alternative_confidence <= r.confidence


def test_aggregation_is_the_mean_log_probability_of_the_cell_frames() -> None:
    classes = ("A", "B", "C")
    x = np.array([-8.0, -2.0, 0.0, 3.0, 7.5, 12.0, 16.0])
    cells = np.array([0.0, 14.0])
    log_probs = torch.log_softmax(
        torch.tensor(
            [
                [0.0, 9.0, 0.0],  # -8: outside +-3.5 of cell 0: ignored
                [2.0, 0.0, 0.0],
                [2.0, 0.0, 0.0],
                [-10.0, 0.0, 5.0],  # one frame is sure it is not A
                [0.0, 0.0, 9.0],  # 7.5: between cells: ignored
                [0.0, 1.0, 0.0],
                [0.0, 3.0, 0.5],
            ]
        ),
        dim=1,
    )
    readings = aggregate(log_probs, x, cells, 14.0, "AB", classes)
    first, second = readings
    expected = torch.softmax(log_probs[1:4].mean(0), 0)
    # the geometric mean reads C; the arithmetic mean of probabilities would have read A
    assert int(log_probs[1:4].exp().mean(0).argmax()) == 0
    assert first.read == "C" and first.n_frames == 3 and not first.correct
    assert first.confidence == pytest.approx(float(expected[2]), rel=1e-6)
    assert first.alternative == "B"
    assert first.alternative_confidence == pytest.approx(float(expected[1]), rel=1e-6)
    assert second.read == "B" and second.n_frames == 2 and second.correct
    assert [f.tolist() for f in cell_frames(x, cells, 14.0)] == [[1, 2, 3], [5, 6]]
    # a step wider than half the pitch leaves no frame in a window: the nearest one is read
    assert [f.tolist() for f in cell_frames(np.array([-5.0, 13.0]), cells, 14.0)] == [[0], [1]]


def _tiny_classifier(path: Path) -> Path:
    from tactile_bench.classify.module import BrailleClassifier
    from tactile_bench.classify.store import save_classifier

    torch.manual_seed(0)
    model = BrailleClassifier(num_classes=len(CHARACTERS), width=2, blocks=(1, 1, 1, 1))
    return save_classifier(model.eval(), path)


def test_cli_reads_with_the_run_dirs_model_and_writes_json_and_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _tiny_classifier(tmp_path / "run" / "classify_diffusion-0123" / "model_seed0.pt")
    assert find_model(tmp_path / "run") == model
    png = tmp_path / "frames.png"
    args = ["read", "--word", "ab", "--run-dir", str(tmp_path / "run"), "--step-mm", "2"]
    assert main([*args, "--json", "--save-frames", str(png)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["word"] == "AB" and len(result["read"]) == 2
    assert result["model"] == str(model) and result["classes"] == "".join(CHARACTERS)
    assert [c["true"] for c in result["cells"]] == ["A", "B"]
    assert all(c["read"] in CHARACTERS and 0 < c["confidence"] <= 1 for c in result["cells"])
    assert result["correct"] == sum(c["correct"] for c in result["cells"])
    assert np.diff([f["x_mm"] for f in result["frames"]]) == pytest.approx(2.0)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    assert main(args) == 0  # the same reading as text: seeded
    out = capsys.readouterr().out.splitlines()
    assert f"word read: {result['read']}  (true AB)" in out[-1]
    cell_lines = [line.split() for line in out if re.match(r"\s+\d+\s+-?\d+\.\d\d\s", line)]
    assert [(c[0], c[2], c[3]) for c in cell_lines] == [
        (str(c["position"]), c["true"], c["read"]) for c in result["cells"]
    ]


def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty_run"
    empty.mkdir()
    cases = [
        (["read", "--word", "DIG1T", "--run-dir", str(empty)], "'1'"),
        (["read", "--run-dir", str(empty)], "fit recipes/quick.yaml"),
        (["read", "--run-dir", str(empty), "--row", "real"], "classify_real-*"),
        (["read", "--model", str(tmp_path / "none.pt")], "none.pt"),
    ]
    for args, needle in cases:
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err and err.startswith("error:")
    assert (
        "classify_diffusion-*"
        in (main(["read", "--run-dir", str(empty)]), capsys.readouterr().err)[1]
    )


@pytest.mark.slow
def test_json_on_stdout_is_clean_in_a_fresh_process(tmp_path: Path) -> None:
    """pybullet's C code prints a build line on stdout at import; --json must stay parseable."""
    import subprocess
    import sys

    model = _tiny_classifier(tmp_path / "model_seed0.pt")
    args = ["--threads", "1", "read", "--word", "A", "--model", str(model), "--json"]
    done = subprocess.run(
        [sys.executable, "-m", "tactile_bench", *args], capture_output=True, text=True, check=True
    )
    assert json.loads(done.stdout)["word"] == "A"
