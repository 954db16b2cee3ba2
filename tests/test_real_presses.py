"""Real ball presses (Taxim's calibration packs): loader, response fit, profiles, grounding.

Synthetic packs in the same layout test the code without the ``taxim`` package; the tests
on the real frames skip cleanly when it is not installed (``pip install -e '.[real]'``).
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.data import ball_presses
from tactile_bench.data.ball_presses import load_ball_presses, sphere_depth
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.press_grounding import contact_mask, fit_sensor, spread
from tactile_bench.sensor.response_fit import fit_response, predict_delta
from tactile_bench.sensor.surrogate import SurrogateDigit

needs_taxim = pytest.mark.skipif(
    importlib.util.find_spec("taxim") is None, reason="taxim not installed ([real])"
)
PIXMM = 0.05  # coarse synthetic frames: 48 x 64 px = 3.2 x 2.4 mm


def _write_pack(
    root: Path,
    n: int = 8,
    hw: tuple[int, int] = (48, 64),
    radius_px: float = 12.0,
    weights: np.ndarray | None = None,
    sigma_mm: float = 0.0,
) -> Path:
    """A pack whose frames are rendered from known spheres with a known response."""
    root.mkdir(parents=True, exist_ok=True)
    gen = np.random.default_rng(0)
    h, w = hw
    yy, xx = np.mgrid[:h, :w]
    f0 = np.stack([100 + 30 * xx / w, 120 - 20 * yy / h, 110 + 0 * xx], -1)
    centres = np.stack([gen.uniform(16, w - 16, n), gen.uniform(14, h - 14, n)], 1)
    radii = np.full(n, radius_px)
    depth = sphere_depth(centres, radii, hw, PIXMM, 3.0)
    gel_mm = (w * PIXMM, h * PIXMM)
    if weights is None:
        imgs = np.repeat(f0[None], n, 0) + 600 * depth[:, 0, :, :, None].numpy()
    else:
        delta = predict_delta(spread(depth, sigma_mm, gel_mm), weights, gel_mm)
        imgs = f0[None] + delta.permute(0, 2, 3, 1).numpy()
    np.savez(
        root / "dataPack.npz",
        f0=f0.round().clip(0, 255).astype(np.uint8),
        imgs=imgs.round().clip(0, 255).astype(np.uint8),
        touch_center=centres,
        touch_radius=radii.astype(np.int64),
    )
    (root / "params.json").write_text(json.dumps({"sensor": {"pixmm": PIXMM}}))
    return root


def test_a_press_becomes_the_sphere_cap_at_its_annotation(tmp_path: Path) -> None:
    pack = _write_pack(tmp_path / "pack")
    presses = load_ball_presses(pack, (48, 64), ball_radius_mm=2.0)
    assert presses.depth.shape == (8, 1, 48, 64) and presses.real.shape == (8, 3, 48, 64)
    r_mm = 12 * PIXMM
    assert float((presses.real - presses.background).abs().amax()) > 20  # presses show
    expected_peak = 2.0 - math.sqrt(2.0**2 - r_mm**2)
    assert float(presses.depth.amax()) == pytest.approx(expected_peak, rel=0.02)
    cx, cy = presses.centres_px[0]
    yy, xx = np.mgrid[:48, :64]
    outside = np.hypot(xx - cx, yy - cy) > 12.5
    assert float(presses.depth[0, 0][torch.from_numpy(outside)].abs().max()) == 0.0
    assert presses.gel_mm == pytest.approx((64 * PIXMM, 48 * PIXMM))
    fit, held = presses.halves()
    assert fit == [0, 2, 4, 6] and held == [1, 3, 5, 7]
    small = load_ball_presses(pack, 16)
    assert small.depth.shape == (8, 1, 16, 16) and small.background.shape == (3, 16, 16)
    # area averaging keeps the mean colour of the frame
    assert float(small.background.mean()) == pytest.approx(float(presses.background.mean()), 0.01)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda p: p.joinpath("params.json").write_text("{}"), "sensor.pixmm"),
        (lambda p: p.joinpath("params.json").unlink(), "params.json: file not found"),
        (lambda p: p.joinpath("dataPack.npz").write_bytes(b"not a zip"), "corrupt"),
    ],
)
def test_a_damaged_pack_is_a_one_line_error_naming_the_file(tmp_path, damage, message) -> None:
    pack = _write_pack(tmp_path / "pack")
    damage(pack)
    with pytest.raises(TactileBenchError, match=message):
        load_ball_presses(pack)


def test_annotations_that_cannot_be_a_ball_press_are_refused(tmp_path: Path) -> None:
    pack = _write_pack(tmp_path / "pack", radius_px=45)  # 2.25 mm > the 2 mm ball
    with pytest.raises(TactileBenchError, match=r"press 0: contact radius 45 px"):
        load_ball_presses(pack)
    assert load_ball_presses(pack, 16, ball_radius_mm=3.0).depth.shape[0] == 8
    with pytest.raises(TactileBenchError, match="larger than the native"):
        load_ball_presses(pack, 100, ball_radius_mm=3.0)
    with pytest.raises(TactileBenchError, match="neither a Taxim sensor"):
        load_ball_presses(tmp_path / "nowhere")


def test_a_missing_taxim_package_says_how_to_install_it(monkeypatch) -> None:
    monkeypatch.setattr(ball_presses.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(TactileBenchError, match=r"pip install -e '\.\[real\]'"):
        load_ball_presses("gelsight")


def test_the_response_fit_recovers_a_known_response(tmp_path: Path) -> None:
    """Frames made by a known compact response: the fit predicts unseen presses exactly."""
    gen = torch.Generator().manual_seed(1)
    weights = torch.randn(22, 3, 6, generator=gen).numpy() * 8
    centres = np.array([[20.0, 20], [40, 25], [30, 30], [45, 18], [25, 28], [35, 22]])
    depth = sphere_depth(centres, np.full(6, 10.0), (48, 64), PIXMM, 2.0)
    gel = (64 * PIXMM, 48 * PIXMM)
    delta = predict_delta(depth, weights, gel)
    fitted = fit_response(depth[:4], delta[:4], gel, ridge=1e-9)
    err = (predict_delta(depth[4:], fitted, gel) - delta[4:]).abs().max()
    assert float(err) < 0.05 * float(delta.abs().max())


def test_the_spread_cross_validation_finds_the_spread_that_made_the_frames(tmp_path) -> None:
    gen = torch.Generator().manual_seed(2)
    weights = torch.randn(22, 3, 6, generator=gen).numpy() * 6
    weights[1:4, :, 0] += 30  # a strong slope response, as a real gel has
    pack = _write_pack(tmp_path / "pack", n=12, weights=weights, sigma_mm=0.6)
    presses = load_ball_presses(pack, (48, 64))
    fit = fit_sensor(presses.depth, presses.real, presses.background, presses.gel_mm)
    assert fit["elastic_sigma_mm"] == 0.6
    assert fit["cv_mse"]["0.6"] < fit["cv_mse"]["0.0"]
    assert np.asarray(fit["background_dct"]).shape == (3, 8, 8)


def test_the_contact_mask_covers_the_contact_and_not_the_far_frame() -> None:
    depth = sphere_depth(np.array([[32.0, 24]]), np.array([8.0]), (48, 64), PIXMM, 2.0)
    mask = contact_mask(depth)
    assert bool(mask[0, 0][depth[0, 0] > 0].all())
    assert not bool(mask[0, 0, 0, 0]) and float(mask.float().mean()) < 0.5


def test_gelsight_profiles_render_with_their_own_gel_and_field() -> None:
    for name, gel_mm in (("gelsight", (18.88, 14.16)), ("gelsight-mini", (18.88, 14.16))):
        sensor = SurrogateDigit.from_profile(name)
        gel = sensor.gel(32)
        assert (gel.width_mm, gel.height_mm) == pytest.approx(gel_mm)
        assert sensor.sensor == name
        flat = sensor.background(32)
        press = torch.zeros(1, 1, 64, 64)
        press[..., 24:40, 24:40] = 0.3
        image = sensor.render_surface(press, gel, torch.Generator().manual_seed(0))
        assert image.shape == (1, 3, 32, 32)
        assert float((image[0] - flat).abs()[:, 12:20, 12:20].mean()) > 3 * float(
            (image[0] - flat).abs()[:, :4, :4].mean()
        )
    digit = SurrogateDigit.from_profile("digit")
    assert (digit.gel().width_mm, digit.gel().height_mm) == (18.0, 24.0)
    assert not torch.equal(
        SurrogateDigit.from_profile("gelsight").background(16), digit.background(16)
    )


def test_ground_with_a_profile_that_has_no_presses_is_a_one_line_error(capsys) -> None:
    assert main(["ground", "--profile", "digit"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no real presses" in err[0]


# ------------------------------------------------------------------ on the real frames
@needs_taxim
def test_the_real_packs_hold_the_presses_the_issue_names() -> None:
    gs, mini = load_ball_presses("gelsight", 32), load_ball_presses("gelsight-mini", 32)
    assert (len(gs), len(mini)) == (48, 24)
    assert gs.frame_hw == mini.frame_hw == (480, 640) and gs.pixmm == pytest.approx(0.0295)
    for p in (gs, mini):  # every press is a contact: the real frame changes where the cap is
        mask = (p.depth > 0).expand_as(p.real)
        change = (p.real - p.background).abs()
        assert float(change[mask].mean()) > 2 * float(change[~mask].mean())


@needs_taxim
@pytest.mark.parametrize("profile", ["gelsight", "gelsight-mini"])
def test_each_profile_beats_the_simple_sim_on_held_out_real_presses(profile) -> None:
    from tactile_bench.real_presses import ground_profile

    report = ground_profile(profile, size=32)
    s = report["summary"]
    assert report["heldout_indices"] == list(range(1, 2 * len(report["presses"]), 2))
    assert s["surrogate"]["contact_mse"]["mean"] < 0.5 * s["sim"]["contact_mse"]["mean"]
    assert s["surrogate"]["contact_mse"]["mean"] < 0.5 * s["no contact"]["contact_mse"]["mean"]


@needs_taxim
def test_real_presses_export_in_the_diagnosis_layout(tmp_path: Path) -> None:
    from tactile_bench.diagnose.paired import load_paired

    out = tmp_path / "pairs"
    assert (
        main(["export-pairs", "--real-presses", "gelsight-mini", "--out", str(out), "--size", "32"])
        == 0
    )
    data = load_paired(out)
    assert len(data) == 24 and data.real.shape == (24, 3, 32, 32)
    assert torch.equal(data.sim_background, data.background)
    assert float(data.depth.amax()) > 0.3  # mm: the ball sinks in, in micrometre PNGs


@pytest.mark.parametrize("figure", ["{tmp}", "{tmp}/sheet.jpg", "{file}/x.png"])
def test_a_figure_path_that_cannot_be_a_png_is_refused_before_any_work(
    tmp_path: Path, capsys, figure: str
) -> None:
    (tmp_path / "f").write_text("a file")
    path = figure.format(tmp=tmp_path, file=tmp_path / "f")
    assert main(["ground", "--profile", "gelsight", "--figure", path]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--figure" in err[0]
    assert list(tmp_path.iterdir()) == [tmp_path / "f"]
