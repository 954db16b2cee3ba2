"""``bench``: a tiny in-process run; the JSON schema; ratios come from measured times."""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

import pytest

from tactile_bench.bench import BenchConfig, run_bench
from tactile_bench.bench.timing import measure, peak_memory
from tactile_bench.cli import main
from tactile_bench.hardware import native_bf16, resolve_precision

# a 50-step schedule keeps the full-chain DDPM baseline (500 steps in a real run) short
TINY_DIFFUSION = {"preset": "tiny", "batch_size": 4, "sample_batch_size": 4, "train_timesteps": 50}
TINY = BenchConfig.quick_preset(
    repeats=2,
    sim_contacts=8,
    sim_frames=2,
    n_finetune=54,
    n_test=27,
    ddpm_images=2,
    default_images=6,
    variant_images=2,
    cases=(("ddim", 1), ("dpmsolver++", 2)),
    presets=("tiny",),
    preset_batch=2,
    train_warmup=1,
    train_steps=1,
    epoch_sizes={"translator": (8, 16, 32), "classifier": (20, 40, 80)},
    fit_steps=2,
    jpeg_images=2,
    jpeg_native_images=1,
    translator_overrides={
        "diffusion": TINY_DIFFUSION,
        "cgan": {"batch_size": 4, "generator_channels": 4, "discriminator_channels": 4},
    },
)


@pytest.fixture(scope="module")
def result(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """The sampling section on a tiny model fitted by the bench itself (no --diffusion)."""
    out = tmp_path_factory.mktemp("bench")
    return run_bench(TINY, out_dir=out, sections=("sampling",), progress=False), out


def test_writes_json_and_markdown_with_the_sampling_schema(result: tuple[dict, Path]) -> None:
    r, out = result
    on_disk = json.loads((out / "bench.json").read_text())
    assert on_disk["machine"]["cores"] >= 1
    assert on_disk["machine"]["torch"]
    assert on_disk["loadavg_start"] is not None and on_disk["loadavg_end"] is not None
    for row in on_disk["sampling"]:
        assert {"sampler", "steps", "images_per_s", "ssim", "speedup_vs_ddpm500"} <= set(row)
        assert row["images_per_s"] > 0 and -1 <= row["ssim"] <= 1
    assert on_disk["sampling"][0]["sampler"] == "ddpm"
    assert on_disk["sampling"][0]["steps"] == TINY_DIFFUSION["train_timesteps"]
    assert "fitted by the bench" in on_disk["sampling_details"]["model"]["source"]
    md = (out / "bench.md").read_text()
    assert "DDPM-50" in md and "| sampler |" in md
    # which precision auto picks on this CPU, and that the default sampler ran in it
    machine = on_disk["machine"]
    auto = resolve_precision("auto")
    assert machine["native_bf16"] == native_bf16() and machine["auto_precision"] == auto
    assert f"`precision: auto` (the default of every config) runs {auto} here" in md
    default = on_disk["sampling_details"]["default"]
    assert default["precision"] == "auto" and default["compute_precision"] == auto
    assert f"precision auto -> {auto} on {machine['cpu_capability']}" in md
    variants = {v["variant"]: v for v in on_disk["sampling_details"]["inference_variants"]}
    assert variants["as configured"]["compute_precision"] == auto
    assert variants["fp32"]["compute_precision"] == "32-true"
    assert variants["bf16"]["compute_precision"] == "bf16-mixed"  # both precisions measured
    assert variants["bf16"]["images_per_s"] > 0
    # the one-conv probe: both precisions timed, the ratio is of the two medians, and bench.md
    # prints them
    probe = machine["conv_probe"]
    assert probe["fp32_ms"] > 0 and probe["bf16_ms"] > 0
    # bench.json rounds every float to 6 decimals, so the ratio agrees to that rounding
    ratio = probe["bf16_ms"] / probe["fp32_ms"]
    assert probe["bf16_over_fp32"] == pytest.approx(ratio, rel=1e-5, abs=2e-6)
    assert f"fp32 {probe['fp32_ms']:.0f} ms, bf16 autocast {probe['bf16_ms']:.0f} ms" in md
    presets = on_disk["sampling_details"]["presets"]
    assert {p["compute_precision"] for p in presets.values()} == {auto}


def _training_result(auto: str, capability: str) -> dict:
    row = {"images_per_s": 10.0, "speedup_vs_fp32": 1.0, "peak_mib": 5.0}
    slow = {"images_per_s": 0.1, "speedup_vs_fp32": 0.01, "peak_mib": 5.0}
    rows = {"fp32": row, "bf16": slow, "fp32+channels_last": row, "bf16+channels_last": slow}
    machine = {"cpu_capability": capability, "native_bf16": auto != "32-true"}
    return {"training": {"classifier": rows}, "machine": machine | {"auto_precision": auto}}


def test_training_table_names_the_cpu_its_bf16_figures_hold_for(bench_markdown) -> None:
    md = bench_markdown(**_training_result("32-true", "AVX2"))
    header = next(line for line in md.splitlines() if line.startswith("| model"))
    assert "| fp32 (auto) | bf16 on AVX2 |" in header
    assert "| fp32+channels_last (auto) | bf16+channels_last on AVX2 |" in header
    assert "0.1 (0.01x)" in md
    assert "All figures measured on AVX2" in md and "trains in 32-true" in md
    md = bench_markdown(**_training_result("bf16-mixed", "AVX512"))
    assert "| fp32 | bf16 on AVX512 (auto) |" in md
    old = _training_result("32-true", "AVX2")  # a bench.json from before precision: auto
    del old["machine"]["auto_precision"], old["machine"]["native_bf16"]
    assert "(auto)" not in bench_markdown(**old)


@pytest.mark.parametrize("name", ["bench.json", "bench_avx2.json"])
def test_a_bench_json_with_the_old_stages_key_still_renders(name: str) -> None:
    """The committed results carry the simulation phases under ``stages`` (the name before
    issue 20); bench.md renders them, and the same as under the new key ``phases``."""
    from tactile_bench.bench.report import render_markdown

    old = json.loads((Path(__file__).resolve().parents[1] / "docs/results" / name).read_text())
    assert "stages" in old["simulation"]["braille"]  # the file is as committed
    md = render_markdown(old)
    assert "Braille, cost per phase" in md and "Objects, cost per phase" in md
    for phase in ("depth", "sim_image", "real_image"):
        assert f"| {phase} |" in md
    new = json.loads(json.dumps(old))
    for section in ("braille", "objects"):
        new["simulation"][section]["phases"] = new["simulation"][section].pop("stages")
    assert render_markdown(new) == md


@pytest.mark.slow
def test_full_tiny_run_covers_every_section(tmp_path: Path) -> None:
    r = run_bench(TINY, out_dir=tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "bench.json").read_text())
    sim = on_disk["simulation"]
    assert sim["braille_contacts_per_s"] > 0 and sim["object_frames_per_s"] > 0
    assert set(sim["braille"]["phases"]) == {"depth", "sim_image", "real_image"}
    assert {"translator:diffusion", "translator:cgan", "classifier"} <= set(r["training"])
    assert set(r["seeds"]) == {"table1", "quick"}
    for rows in r["scaling"]["epoch"].values():
        assert list(rows) == ["1x", "2x", "4x"]
    for rows in r["training"].values():
        assert rows["fp32"]["speedup_vs_fp32"] == pytest.approx(1.0)
        bf16 = rows["bf16"]
        # emulated bf16 (AVX2) is timed over a couple of steps only, native over all of them
        assert bf16["emulated_bf16"] is (not native_bf16())
        assert rows["fp32"]["emulated_bf16"] is False
        assert bf16["speedup_vs_fp32"] == pytest.approx(
            bf16["images_per_s"] / rows["fp32"]["images_per_s"]
        )
    assert len(r["threads"]) == 3 and all("error" not in row for row in r["threads"])
    assert r["threads"][0]["vs_first"] == pytest.approx(1.0)
    md = (tmp_path / "bench.md").read_text()
    assert "OpenMP" in md
    assert "Contact simulation" in md and "linearity" in md and "Training throughput" in md
    assert "worker start-up" in md and "marginal rate" in md and "per CPU-s" in md
    assert r["jpeg"]["headline"] == "effect" and "JPEG codecs" in md and "**Verdict**" in md


def test_ratios_are_computed_from_the_measured_times(result: tuple[dict, Path]) -> None:
    r, _ = result
    rows = r["sampling"]
    base = rows[0]
    assert base["speedup_vs_ddpm500"] == pytest.approx(1.0)
    for row in rows:
        timing = row["timing"]
        median = statistics.median(timing["wall_s"])
        assert row["images_per_s"] == pytest.approx(row["images"] / median, rel=1e-3)
        assert row["speedup_vs_ddpm500"] == pytest.approx(
            row["images_per_s"] / base["images_per_s"], rel=1e-6
        )
    # a 1- or 2-step solver on the same contacts beats 50 DDPM steps: measured, not set
    fast = [row for row in rows if row["steps"] <= 2]
    assert fast and all(row["speedup_vs_ddpm500"] > 3 for row in fast)
    assert len({round(row["speedup_vs_ddpm500"], 6) for row in rows}) == len(rows)
    check = r["sampling_details"]["default_check"]
    assert check["speedup_vs_ddpm500"]["value"] == pytest.approx(
        next(row for row in rows if row["default"])["speedup_vs_ddpm500"]
    )
    assert check["all_met"] == all(
        c["value"] >= c["target"] for k, c in check.items() if k != "all_met"
    )


def test_measure_uses_medians_of_wall_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a clock that only the measured calls advance (a loaded machine cannot move it)."""
    clock = [0.0]
    monkeypatch.setattr(time, "perf_counter", lambda: clock[0])
    delays = iter([5.0, 0.03, 0.01, 0.02])  # warm-up, then three timed calls

    def run() -> None:
        clock[0] += next(delays)

    timing = measure(run, work=10, repeats=3, warmup=1, memory=False)
    assert timing.wall_s == pytest.approx([0.03, 0.01, 0.02])
    assert timing.median_wall_s == pytest.approx(0.02)
    assert timing.per_s == pytest.approx(10 / 0.02)


def test_peak_memory_sees_a_large_temporary() -> None:
    import torch

    with peak_memory() as mem:
        x = torch.ones(64, 2**20 // 4)  # 64 MiB, touched
        time.sleep(0.02)
        del x
    assert mem.delta_mib > 32


def test_cli_names_a_missing_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(["bench", "--diffusion", str(tmp_path / "none.pt"), "--out", str(tmp_path)])
    assert code == 2
    assert "none.pt" in capsys.readouterr().err
    assert not (tmp_path / "bench.json").exists()


def test_object_builds_count_the_worker_processes_cpu() -> None:
    """``time.process_time`` misses the worker processes: their reported CPU is added."""
    from tactile_bench.bench.simulation import measure_with_workers

    t = measure_with_workers(lambda: 5.0, work=10, repeats=2)
    assert len(t.cpu_s) == 2 and all(5.0 <= c < 5.5 for c in t.cpu_s)
    assert t.per_cpu_s < 10 / 5.0


@pytest.mark.slow
def test_objects_are_built_at_the_amortised_size() -> None:
    from tactile_bench.bench.simulation import objects

    r = objects(2, 1, ("037_scissors",), amortised=40)
    assert r["scaling"]["4x"]["work"] >= 40 and r["scaling"]["1x"]["work"] >= 10
    assert r["first_build_s"] > 0 and r["frames_per_s"] == r["scaling"]["4x"]["per_s"]
    assert r["marginal"]["frames_per_cpu_s"] > 0


def test_the_seeds_row_times_both_ways_and_reports_their_ratio(result: tuple[dict, Path]) -> None:
    import torch

    from tactile_bench.bench.report import render_markdown
    from tactile_bench.bench.training import SEED_SETTINGS, seed_batching

    g = torch.Generator().manual_seed(0)
    fg, labels = torch.rand(24, 3, 32, 32, generator=g), torch.arange(24) % 4
    rows = seed_batching(fg, labels, images=24, seeds=2)
    assert set(rows) == set(SEED_SETTINGS)
    for row in rows.values():
        assert row["in_turn_s"] > 0 and row["batched_s"] > 0
        assert row["speedup"] == pytest.approx(row["in_turn_s"] / row["batched_s"])
    md = render_markdown({**result[0], "seeds": rows})
    assert "one batched model" in md and f"{rows['table1']['speedup']:.2f}x" in md
