"""The surrogate DIGIT: profiles, rendering contract, switching effects, grounding."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from tactile_bench.effects import EFFECT_ORDER
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor import grounding
from tactile_bench.sensor.background import digit_background, sim_background
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import HeightFieldBank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit, available_profiles

GEL = GelSpec(size=32, oversample=2)


@pytest.fixture(scope="module")
def bank() -> HeightFieldBank:
    """Two synthetic 'characters': one and two 0.9 mm domes on a flat block (no ray casting)."""
    n, half = 81, 6.0
    t = torch.linspace(-half, half, n)
    yy, xx = torch.meshgrid(-t, t, indexing="ij")

    def dome(cx: float, cy: float) -> torch.Tensor:
        r2 = (xx - cx) ** 2 + (yy - cy) ** 2
        return 0.9 * (1 - r2 / 0.75**2).clamp(min=0).sqrt()

    block = torch.where((xx.abs() < 4) & (yy.abs() < 5), 0.0, -1.0)
    maps = torch.stack([block + dome(0, 0), block + dome(-1.2, 1.2) + dome(1.2, -1.2)])
    return HeightFieldBank(
        maps=maps[:, None].float(), chars=("A", "B"), half_extent_mm=half, far_mm=-1.0,
        spec=BrailleSpec(),
    )  # fmt: skip


def _poses(n: int = 4) -> Poses:
    return Poses(
        labels=torch.arange(n) % 2,
        x_mm=torch.linspace(-2, 2, n),
        y_mm=torch.linspace(1, -1, n),
        yaw_deg=torch.linspace(-25, 25, n),
        press_mm=torch.full((n,), 0.6),
    )


def test_profiles_load() -> None:
    assert {"digit", "digit-b"} <= set(available_profiles())
    digit = SurrogateDigit.from_profile("digit")
    assert digit.effects_enabled == list(EFFECT_ORDER)
    b = SurrogateDigit.from_profile("digit-b")
    assert b.unit == "digit-b"
    assert b.params("led_diffusivity")["diffusion"] != digit.params("led_diffusivity")["diffusion"]
    assert not torch.allclose(digit.background(GEL), b.background(GEL), atol=5.0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("name: x\neffects:\n  nope: {}\n", r"bad\.yaml: effects\.nope: unknown effect"),
        ("effects:\n  shadows: {strength: 7}\n", r"bad\.yaml: effects\.shadows\.strength"),
        ("effects:\n  shadows: {opacity: 0.1}\n", r"bad\.yaml: effects\.shadows\.opacity"),
        ("colour: red\n", r"bad\.yaml: colour: unknown key"),
        ("unit: digit-z\n", r"bad\.yaml: unit"),
        ("effects: [a, b]\n", r"bad\.yaml: effects"),
        ("effects: {shadows: [1]}\n", r"bad\.yaml: effects\.shadows"),
        ("- just\n- a list\n", r"bad\.yaml: must be a mapping"),
    ],
)
def test_profile_errors_name_file_and_key(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(TactileBenchError, match=match):
        SurrogateDigit.from_profile(path)


def test_missing_profile() -> None:
    with pytest.raises(TactileBenchError, match="no such surrogate profile.*digit"):
        SurrogateDigit.from_profile("no-such-unit")


def test_render_contract_and_determinism(bank: HeightFieldBank) -> None:
    s = SurrogateDigit.from_profile("digit")
    poses = _poses()
    a = s.render(bank, poses, GEL, torch.Generator().manual_seed(3))
    b = s.render(bank, poses, GEL, torch.Generator().manual_seed(3))
    c = s.render(bank, poses, GEL, torch.Generator().manual_seed(4))
    assert a.shape == (4, 3, 32, 32) and a.dtype == torch.float32
    assert float(a.min()) >= 0 and float(a.max()) <= 255
    assert torch.equal(a, b) and not torch.equal(a, c)
    bg = s.background(GEL)
    assert bg.shape == (3, 32, 32)
    # a contact shows up against this unit's no-contact frame
    assert float((a - bg).abs().amax(dim=(1, 2, 3)).min()) > 20


def test_background_is_the_no_contact_render() -> None:
    s = SurrogateDigit.from_profile("digit").without("camera_noise")
    flat = torch.zeros(2, 1, 64, 64) - 0.5  # object 0.5 mm away from the gel
    frames = s.render_surface(flat, GEL, torch.Generator().manual_seed(0))
    assert torch.allclose(frames, s.background(GEL).expand(2, -1, -1, -1), atol=1e-3)


def test_all_effects_off_is_the_noise_free_simulator(bank: HeightFieldBank) -> None:
    bare = SurrogateDigit({}, unit="digit")
    assert bare.effects_enabled == []
    poses = _poses()
    ours = bare.render(bank, poses, GEL)
    depth = to_depth(render_height(bank, poses, GEL), GEL)
    sim = SimOptics().render(depth, sim_background(GEL.size), None, GEL)
    assert torch.allclose(ours, sim, atol=1e-3)
    assert torch.allclose(bare.background(GEL), digit_background(GEL.size), atol=1e-4)


def test_default_surrogate_differs_from_sim_substantially(bank: HeightFieldBank) -> None:
    """The gap the benchmark studies: foregrounds of the same contacts differ a lot."""
    real = SurrogateDigit.from_profile("digit")
    bare = SurrogateDigit({})
    poses = _poses()
    fg_real = real.render(bank, poses, GEL) - real.background(GEL)
    fg_sim = bare.render(bank, poses, GEL) - bare.background(GEL)
    gap = float((fg_real - fg_sim).abs().mean())
    assert gap > 1.0


def test_render_pinned_to_the_reference_implementation(bank: HeightFieldBank) -> None:
    """Statistics of a fixed render, recorded with the original (per-op, conv2d / grid_sample /
    interpolate) implementation before the surrogate was vectorised. The fast one differs
    from it only by float rounding: per-pixel mean |diff| 2e-5 DN, max 0.6 DN (a JPEG
    coefficient on a rounding boundary), so these agree to ~1e-4."""
    k = 40
    poses = Poses(
        labels=torch.arange(k) % 2,
        x_mm=torch.linspace(-2, 2, k),
        y_mm=torch.linspace(1, -1, k),
        yaw_deg=torch.linspace(-25, 25, k),
        press_mm=torch.linspace(0.3, 0.9, k),
    )
    s, gel = SurrogateDigit.from_profile("digit"), GelSpec(size=64)
    img = s.render(bank, poses, gel, torch.Generator().manual_seed(7))
    fg = (img - s.background(gel)).abs()
    ref = {
        "mean": [111.86053, 100.86792, 105.93949],
        "std": [45.11437, 17.44935, 21.67302],
        "fg_abs_mean": [1.659515, 1.358716, 1.697897],
    }
    ours = {
        "mean": img.mean(dim=(0, 2, 3)),
        "std": img.std(dim=(0, 2, 3)),
        "fg_abs_mean": fg.mean(dim=(0, 2, 3)),
    }
    for key, values in ref.items():
        assert torch.allclose(ours[key], torch.tensor(values), rtol=1e-4, atol=1e-3), key
    assert abs(float(fg.amax()) - 79.73769) < 0.05


def test_without_only_with_params() -> None:
    s = SurrogateDigit.from_profile("digit")
    w = s.without("shadows", "jpeg")
    assert "shadows" not in w.effects_enabled and "jpeg" not in w.effects_enabled
    assert len(w.effects_enabled) == len(s.effects_enabled) - 2
    assert "shadows" in s.effects_enabled  # the original is untouched
    assert s.only("elastic_spread").effects_enabled == ["elastic_spread"]
    t = w.with_params("shadows", strength=0.2)
    assert "shadows" in t.effects_enabled and t.params("shadows")["strength"] == 0.2
    with pytest.raises(TactileBenchError, match="unknown effect"):
        s.without("no_such_effect")
    with pytest.raises(TactileBenchError, match="shadows.*strength"):
        s.with_params("shadows", strength=9.0)
    assert s.to_dict()["effects"]["shadows"] == {}


def test_each_effect_carries_part_of_the_image(bank: HeightFieldBank) -> None:
    """Switching any one effect off changes the rendered contact images (at S = 64, where
    the defocus PSF spans a pixel)."""
    s = SurrogateDigit.from_profile("digit")
    poses, gel = _poses(1), GelSpec(size=64)
    ref = s.render(bank, poses, gel, torch.Generator().manual_seed(0))
    for name in s.effects_enabled:
        other = s.without(name).render(bank, poses, gel, torch.Generator().manual_seed(0))
        assert not torch.allclose(ref, other, atol=1e-3), name


def test_render_surface_without_a_bank() -> None:
    s = SurrogateDigit.from_profile("digit")
    height = torch.zeros(1, 1, 48, 48) - 0.2
    height[..., 20:28, 20:28] = 0.4  # a square punch, any resolution
    img = s.render_depth_image(height, GEL, torch.Generator().manual_seed(0))
    assert img.shape == (1, 3, 32, 32)
    with pytest.raises(TactileBenchError, match="height must be"):
        s.render_surface(torch.zeros(1, 48, 48), GEL)


def test_digit_background_units() -> None:
    bg = digit_background(64)
    assert bg.shape == (3, 64, 64) and float(bg.min()) >= 0 and float(bg.max()) <= 255
    assert torch.equal(sim_background(64), bg)
    assert digit_background((32, 24)).shape == (3, 32, 24)
    # reddish upper left, green right (the measured frame's layout)
    assert float(bg[0, :24, :24].mean()) > float(bg[0, :, 40:].mean())
    assert float(bg[1, :, 48:].mean()) > float(bg[1, :, :16].mean())
    with pytest.raises(TactileBenchError, match="unknown DIGIT unit"):
        digit_background(64, "digit-q")


# --------------------------------------------------------------------------- grounding
REAL = grounding.default_real_dir()
needs_real = pytest.mark.skipif(REAL is None, reason="../shared/real not present")


@needs_real
def test_background_grounding() -> None:
    rep = grounding.background_report(REAL)
    assert rep is not None
    assert rep["mean_abs_diff_of_means"] < 1.0
    assert rep["lowfreq_rmse"] < 5.0  # measured 3.1
    assert rep["rmse"] < 6.0  # measured 4.8 (JPEG texture and the rim are not modelled)
    for ours, real in zip(rep["surrogate_std"], rep["real_std"], strict=True):
        assert abs(ours - real) < 0.1 * real


@needs_real
def test_optical_response_grounding() -> None:
    rep = grounding.optical_response_report(REAL)
    assert rep is not None
    assert rep["mae"] < 4.0  # measured 3.37 on 0-255, table mean |value| 32
    assert rep["relative_error"] < 0.15
    torch_rep = grounding.surrogate_response_report(REAL)
    assert torch_rep is not None and torch_rep["mae"] < 4.0  # the torch path renders the fit


def test_grounding_skips_cleanly_without_files(tmp_path: Path) -> None:
    rep = grounding.grounding_report(tmp_path)
    assert rep == {
        "background": None,
        "background_digit_b": None,
        "optical_response": None,
        "surrogate_response": None,
    }
