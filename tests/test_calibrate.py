"""calibrate: a profile of the user's own sensor from paired frames, scored on held-out pairs."""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from tactile_bench.calibrate import commands
from tactile_bench.calibrate.curve import curve_sizes
from tactile_bench.calibrate.fit import dct_field, fit_dct, match_no_contact, profile_effects
from tactile_bench.calibrate.run import DEFAULT_HOLDOUT, calibrate_pairs, min_pairs
from tactile_bench.diagnose.paired import DiagnosisPairs, load_paired, write_paired
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.effects.optics import sensor_optics
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.grounding import fit_background_dct
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.response_fit import predict_delta
from tactile_bench.sensor.surrogate import SurrogateDigit

SIZE = 20
FAST = ("vignetting",)  # one cheap candidate: the selection runs in a second


@pytest.fixture(scope="module")
def pairs() -> DiagnosisPairs:
    """14 braille pairs whose 'real' sensor answers light like the GelSight, not the sim."""
    data = planted_pairs(build_bank(("A", "L"), BrailleSpec()), {}, 14, 3, SIZE)
    weights = sensor_optics("gelsight")[0].numpy()
    real = data.background[None] + predict_delta(data.depth, weights, data.gel_mm)
    return dataclasses.replace(data, real=real.round().clamp(0, 255), gel_mm=(18.88, 14.16))


@pytest.fixture(scope="module")
def folder(pairs: DiagnosisPairs, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_paired(tmp_path_factory.mktemp("cal") / "pairs", pairs)


def _run(*args: str) -> int:
    """``calibrate`` through its own parser (the CLI adds it with ``register``)."""
    parser = argparse.ArgumentParser()
    commands.register(parser.add_subparsers())
    ns = parser.parse_args(["calibrate", *args])
    return ns.func(ns)


def _nothing_written(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]


# ----------------------------------------------------------------------------- the command
def test_calibrate_writes_a_profile_that_beats_the_plain_sim(folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "cal"
    assert _run(str(folder), "--out", str(out), "--size", str(SIZE), "--no-progress") == 0
    assert {p.name for p in out.iterdir()} == {"profile.yaml", "calibration.json", "calibration.md"}
    report = json.loads((out / "calibration.json").read_text())
    assert (report["n_pairs"], report["n_fit"], report["n_heldout"]) == (14, 7, 7)
    assert "optical_response" in report["selected"]
    held = report["heldout"]
    assert held["profile"]["contact_mse"] < 0.2 * held["sim"]["contact_mse"]
    assert set(report["timing_s"]) >= {"split", "background", "selection", "lookup", "scoring"}
    profile = SurrogateDigit.from_profile(out / "profile.yaml")
    assert profile.gel(SIZE).width_mm == pytest.approx(18.88)
    # the frames are noise-free: the measured camera noise is 0, and none is added
    assert report["noise"]["read_noise"] == 0 and "camera_noise" not in profile.effects_enabled
    assert profile.effects_enabled[-1] == "optical_response"
    image = profile.render_surface(torch.zeros(1, 1, 2 * SIZE, 2 * SIZE), profile.gel(SIZE))
    assert image.shape == (1, 3, SIZE, SIZE) and bool(image.isfinite().all())
    text = (out / "calibration.md").read_text()
    assert f"--profile {out / 'profile.yaml'}" in text and "second_unit:" in text
    assert "| profile |" in text


def test_holdout_zero_fits_every_pair_and_reports_no_heldout(
    pairs: DiagnosisPairs, tmp_path: Path
) -> None:
    out = tmp_path / "all"
    result = calibrate_pairs(pairs, out, holdout=0, progress=False, candidates=FAST)
    assert (result["n_fit"], result["n_heldout"], result["heldout"]) == (14, 0, None)
    assert "--holdout 0" in (out / "calibration.md").read_text()
    assert json.loads((out / "calibration.json").read_text())["heldout"] is None
    SurrogateDigit.from_profile(out / "profile.yaml")


def test_curve_scores_nested_subsets_on_the_same_heldout(
    pairs: DiagnosisPairs, tmp_path: Path
) -> None:
    out = tmp_path / "curve"
    result = calibrate_pairs(pairs, out, curve=True, progress=False, candidates=FAST)
    rows = result["curve"]["rows"]
    assert [r["n_presses"] for r in rows] == [4, 7]
    assert rows[-1]["contact_mse"] == result["heldout"]["profile"]["contact_mse"]
    assert all(r["contact_mse"] < result["curve"]["sim"]["contact_mse"] for r in rows)
    assert (out / "curve.png").stat().st_size > 0
    assert "| 4 |" in (out / "calibration.md").read_text()


def test_a_failure_leaves_nothing_and_keeps_what_was_there(
    pairs: DiagnosisPairs, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tactile_bench.calibrate import report

    def broken(folder: Path, result: dict) -> None:
        (folder / "calibration.json").write_text("{")
        raise OSError("disk went away")

    monkeypatch.setattr(report, "write_report", broken)
    out = tmp_path / "cal"
    with pytest.raises(OSError, match="disk went away"):
        calibrate_pairs(pairs, out, progress=False, candidates=FAST)
    _nothing_written(out)
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OSError, match="disk went away"):
        calibrate_pairs(pairs, out, progress=False, candidates=FAST, overwrite=True)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    with pytest.raises(TactileBenchError, match="not empty; pass --overwrite"):
        calibrate_pairs(pairs, out, progress=False, candidates=FAST)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "args, match",
    [
        (("--holdout", "1"), "--holdout: the held-out share must be in \\[0, 1\\), got 1"),
        (("--holdout", "-0.1"), "--holdout: the held-out share must be in"),
        (("--holdout", "0", "--curve"), "--curve: needs held-out pairs"),
    ],
)
def test_bad_holdout_is_one_line_before_reading(
    args: tuple[str, ...], match: str, tmp_path: Path
) -> None:
    out = tmp_path / "cal"
    with pytest.raises(TactileBenchError, match=match) as err:
        _run(str(tmp_path / "no_such_folder"), "--out", str(out), *args)
    assert "\n" not in str(err.value)
    _nothing_written(out)


def _copy(folder: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(folder, tmp_path / "pairs"))


def _break_too_few(root: Path) -> Path:
    for victim in sorted((root / "depth").rglob("*.png"))[7:]:
        for part in ("depth", "sim", "real"):
            (root / part / victim.relative_to(root / "depth")).unlink()
    return root


def _break_no_depth(root: Path) -> Path:
    shutil.rmtree(root / "depth")
    return root / "depth"


def _break_mixed_sizes(root: Path) -> Path:
    victim = sorted((root / "real").rglob("*.png"))[3]
    Image.fromarray(np.zeros((SIZE + 4, SIZE + 4, 3), np.uint8)).save(victim)
    return victim


def _break_background(root: Path) -> Path:
    Image.fromarray(np.zeros((SIZE + 6, SIZE + 6, 3), np.uint8)).save(root / "background.png")
    return root / "background.png"


def _break_depth_bits(root: Path) -> Path:
    victim = sorted((root / "depth").rglob("*.png"))[2]
    Image.fromarray(np.zeros((SIZE, SIZE), np.uint8)).save(victim)
    return victim


@pytest.mark.parametrize(
    "breaker, match",
    [
        (_break_too_few, "7 pairs; calibrate needs at least 4 to fit .* 8 or more"),
        (_break_no_depth, "folder not found; a paired folder holds depth/"),
        (_break_mixed_sizes, f"is {SIZE + 4} x {SIZE + 4}, the other images are {SIZE} x {SIZE}"),
        (_break_background, f"is {SIZE + 6} x {SIZE + 6}, the other images are {SIZE} x"),
        (_break_depth_bits, "depth must be one 16-bit grey channel in micrometres"),
    ],
)
def test_bad_folder_is_one_line_naming_the_file(
    breaker, match: str, folder: Path, tmp_path: Path
) -> None:
    root = _copy(folder, tmp_path)
    culprit = breaker(root)
    out = tmp_path / "cal"
    with pytest.raises(TactileBenchError, match=match) as err:
        _run(str(root), "--out", str(out), "--no-progress")
    message = str(err.value)
    assert "\n" not in message and (str(culprit) in message or str(root) in message)
    _nothing_written(out)


def test_too_few_pairs_says_how_many() -> None:
    assert min_pairs(0.5) == 8 and min_pairs(0) == 4 and min_pairs(0.25) == 8


def test_a_folder_without_sim_gets_the_plain_simulator(folder: Path, tmp_path: Path) -> None:
    root = _copy(folder, tmp_path)
    shutil.rmtree(root / "sim")
    data = load_paired(root, render_missing_sim=True)
    assert data.sim.shape == data.real.shape and data.sim_background is None
    with pytest.raises(TactileBenchError, match="sim: folder not found"):
        load_paired(root)


# ----------------------------------------------------------------------------- the parts
def test_the_profile_carries_what_a_profile_can_and_says_what_it_drops() -> None:
    selected = {
        "pose_error": {"offset_x_mm": 0.2},
        "elastic_spread": {"sigma_mm": 1.1},
        "gel_wear": {"measured_wear": 0.4},
        "led_diffusivity": {"gain_r": 1.2},
        "optical_response": {"blend": 0.7},
    }
    effects, dropped = profile_effects(selected)
    assert list(effects) == ["elastic_spread", "optical_response", "led_diffusivity"]
    # parameters the candidate held at neutral are written out: a profile fills defaults
    assert effects["elastic_spread"]["contact_scale"] == 0.4
    assert effects["led_diffusivity"]["diffusion"] == 0.0
    assert effects["optical_response"] == {"blend": 1.0}
    assert set(dropped) == {"pose_error", "gel_wear.measured_wear", "gel_wear"}
    # without the response, an LED mix was fitted on the sim's own shading: not carried
    effects, dropped = profile_effects({"led_diffusivity": {"gain_r": 1.2}, "vignetting": {}})
    assert list(effects) == ["optical_response"] and "led_diffusivity" in dropped
    assert "vignetting" in dropped  # neutral: nothing to carry


def test_the_no_contact_field_is_matched_through_the_profiles_own_effects() -> None:
    rng = np.random.default_rng(0)
    coef = np.zeros((3, 4, 4))
    coef[:, 0, 0] = 120.0
    coef[:, :2, :2] += rng.normal(0, 10, (3, 2, 2))
    sensor = {
        "gel_mm": [18.0, 24.0],
        "background_dct": coef,
        "response_weights": np.zeros((22, 3, 6)),
        "led_azimuth_deg": [0.0, 120.0, 240.0],
    }
    effects = {"led_diffusivity": {"gain_r": 1.3, "gain_g": 0.8, "gain_b": 1.0}}
    matched, rms = match_no_contact(effects, sensor, 16)
    assert rms[0] > 10 and rms[-1] < 0.1
    own = {"optical_response": {"blend": 1.0}}
    assert match_no_contact(own, sensor, 16)[1] == [0.0]  # nothing changes the field
    assert not np.allclose(matched, coef)


def test_the_cosine_fit_is_the_least_squares_fit_and_its_field() -> None:
    image = np.random.default_rng(1).uniform(0, 255, (12, 16, 3))
    for k in (2, 5, 12):
        np.testing.assert_allclose(fit_dct(image, k), fit_background_dct(image, k), atol=1e-8)
    square = image[:, :12]  # as many terms as pixels: the field is the frame
    np.testing.assert_allclose(dct_field(fit_dct(square, 12), 12, 12), square, atol=1e-6)


def test_curve_points_and_the_default_holdout() -> None:
    assert curve_sizes(24) == [4, 8, 16, 24] and curve_sizes(16) == [4, 8, 16]
    assert curve_sizes(4) == [4]
    assert commands.DEFAULT_HOLDOUT == DEFAULT_HOLDOUT == 0.5
