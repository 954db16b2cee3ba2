"""Where the diagnosis spends its time (issue 47): the span breakdown in report.json, the
``--timing`` lines, the same answer with and without a timer, and the bench's row.

Tiny pairs (12 at 16 px) and two cheap candidates: the tests check the accounting, not
the figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from tactile_bench.bench import BenchConfig, run_bench
from tactile_bench.cli import main
from tactile_bench.diagnose import breakdown
from tactile_bench.diagnose.paired import DiagnosisPairs, write_paired
from tactile_bench.diagnose.run import stratified_split
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.timing import SpanTimer

SIZE = 16
CANDIDATES = ["vignetting", "gamma_white_balance"]


@pytest.fixture(scope="module")
def pairs() -> DiagnosisPairs:
    bank = build_bank(("A", "L"), BrailleSpec())
    return planted_pairs(bank, {"vignetting": {"corner_loss": 0.35}}, 12, 3, SIZE)


@pytest.fixture
def short_encoder(monkeypatch: pytest.MonkeyPatch) -> None:
    """A few encoder steps: KID's figures do not matter here, only that it is timed."""
    monkeypatch.setattr("tactile_bench.diagnose.shrink.ENCODER_STEPS", 5)


def test_the_report_holds_every_span_and_they_add_up_to_the_total(
    pairs: DiagnosisPairs,
    tmp_path: Path,
    short_encoder: None,
    capsys: pytest.CaptureFixture[str],
) -> None:
    root = write_paired(tmp_path / "pairs", pairs)
    out = tmp_path / "out"
    args = ["diagnose", str(root), "--out", str(out), "--no-downstream", "--no-progress"]
    assert main([*args, "--candidates", *CANDIDATES, "--timing"]) == 0
    stdout = capsys.readouterr().out
    timing = json.loads((out / "report.json").read_text())["timing_s"]
    spans = timing["breakdown"]
    fits = spans[breakdown.MAIN_FIT.candidate_fit]
    assert fits["calls"] >= len(CANDIDATES)  # every candidate fitted alone, each its call
    assert fits["inclusive_seconds"] >= fits["seconds"] > 0
    expected = {
        breakdown.DIAGNOSE,
        breakdown.WHERE,
        breakdown.WHICH,
        breakdown.MAIN_FIT.setup,
        breakdown.MAIN_FIT.select,
        breakdown.DEPTH_SPLIT,  # 12 pairs: enough for the depth split
        breakdown.DEPTH_SPLIT_FIT.candidate_fit,
        breakdown.BOOTSTRAP,
        breakdown.RENDER,
        breakdown.GAP,
        breakdown.HOW_FAR,
        breakdown.KID,
        breakdown.REPORT,
        breakdown.REPORT_FIGURES,
    }
    assert expected <= set(spans)
    assert breakdown.DOWNSTREAM not in spans  # --no-downstream: no classifier trained
    assert spans[breakdown.RENDER]["calls"] > fits["calls"]  # a fit renders many times
    assert spans[breakdown.DEPTH_SPLIT_FIT.candidate_fit]["calls"] == len(CANDIDATES)
    for row in spans.values():
        assert row["calls"] >= 1 and row["seconds"] >= 0
        assert row["inclusive_seconds"] >= row["seconds"] - 1e-9
    # exclusive seconds partition the run: they add up to (just under) its total
    covered = sum(row["seconds"] for row in spans.values())
    assert 0.9 * timing["total"] <= covered <= timing["total"]
    assert spans[breakdown.DIAGNOSE]["inclusive_seconds"] <= timing["total"]
    # printed most seconds first (report.json's keys are sorted by name)
    printed = stdout.split("where the time went", 1)[1].splitlines()[2:]
    names = [line.split()[0] for line in printed if line.startswith("  ")]
    assert set(names) == set(spans)
    seconds = [spans[name]["seconds"] for name in names]
    assert seconds == sorted(seconds, reverse=True)
    page = (out / "report.html").read_text()
    assert "<th>span</th><th>calls</th>" in page and breakdown.MAIN_FIT.candidate_fit in page


def test_the_answer_is_the_same_with_and_without_a_timer(pairs: DiagnosisPairs) -> None:
    fit_idx, held_idx = stratified_split(pairs.labels, 0.5, 0)

    def answer() -> tuple:
        result = explain_gap(pairs, fit_idx, held_idx, CANDIDATES, progress=False)
        rows = [(r.effect, r.params, r.shrink, r.ci_low, r.ci_high) for r in result.singles]
        return rows, result.selected_params, result.unexplained, result.stability

    plain = answer()
    with SpanTimer() as timer:
        timed = answer()
    assert timed == plain
    assert timer.calls[breakdown.MAIN_FIT.candidate_fit] == len(CANDIDATES)
    assert timer.calls[breakdown.RENDER] > 0 and timer.wall[breakdown.GAP] > 0
    assert set(timer.wall) == set(timer.calls) == set(timer.inclusive)


def test_spans_nest_and_count_their_calls() -> None:
    from tactile_bench.sensor.timing import timed_span

    with SpanTimer() as timer:
        for _ in range(3):
            with timed_span("outer"):
                torch.ones(1000).sum()
                with timed_span("inner"):
                    torch.ones(1000).sum()
    rows = breakdown.breakdown(timer)
    assert rows["outer"]["calls"] == 3 and rows["inner"]["calls"] == 3
    outer = rows["outer"]
    assert outer["inclusive_seconds"] == pytest.approx(
        outer["seconds"] + rows["inner"]["inclusive_seconds"]
    )
    lines = breakdown.breakdown_lines(rows, top=1)
    assert len(lines) == 2 and ("outer" in lines[1] or "inner" in lines[1])


def test_the_bench_section_writes_its_row(tmp_path: Path, short_encoder: None) -> None:
    cfg = BenchConfig.quick_preset(
        repeats=1,
        conv_batch=1,
        diagnosis_pairs=12,
        diagnosis_size=SIZE,
        diagnosis_candidates=tuple(CANDIDATES[:1]),
        diagnosis_downstream=False,
    )
    run_bench(cfg, out_dir=tmp_path, sections=("diagnosis",), progress=False)
    row = json.loads((tmp_path / "bench.json").read_text())["diagnosis"]
    assert row["pairs"] == 12 and row["size"] == SIZE and row["downstream"] is False
    assert row["candidates"] == CANDIDATES[:1] and row["fit_fraction"] == 0.5
    assert row["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert row["wall_s"] > 0 and row["which_s"] > 0 and row["how_far_s"] > 0
    assert row["wall_s"] >= row["which_s"] + row["how_far_s"]
    assert row["peak_rss_mib"] > 0
    assert set(row["steps_s"]) == {"where", "which", "how_far", "samples", "report"}
    top = [r["span"] for r in row["top_spans"]]
    assert breakdown.MAIN_FIT.candidate_fit in row["breakdown"]
    seconds = sorted((r["seconds"] for r in row["breakdown"].values()), reverse=True)
    assert [r["seconds"] for r in row["top_spans"]] == seconds[: len(top)]
    assert len(top) == min(12, len(seconds))
    md = (tmp_path / "bench.md").read_text()
    assert "## Gap diagnosis" in md and f"| `{top[0]}` |" in md


def test_bench_only_diagnosis_keeps_the_wait_policy_diagnose_keeps() -> None:
    from tactile_bench.cli import build_parser
    from tactile_bench.diagnose.commands import KEEP_OMP_WAIT_POLICY

    parser = build_parser()
    alone = parser.parse_args(["bench", "--only", "diagnosis", "--quick"])
    assert alone.only == ["diagnosis"] and alone.omp_wait_policy == KEEP_OMP_WAIT_POLICY
    assert parser.parse_args(["diagnose", "p", "--out", "o"]).omp_wait_policy == (
        KEEP_OMP_WAIT_POLICY
    )
    for args in (["bench", "--only", "diagnosis", "jpeg"], ["bench"]):
        assert not hasattr(parser.parse_args(args), "omp_wait_policy")  # the CLI's PASSIVE
