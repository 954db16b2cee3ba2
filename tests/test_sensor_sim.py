"""Height fields, contact depth and the simple simulator's optics."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry import BrailleSpec, Poses, dot_positions
from tactile_bench.sensor import heightfield
from tactile_bench.sensor.depth import GelSpec, render_depth, render_height, to_depth
from tactile_bench.sensor.heightfield import HeightFieldBank, build_bank
from tactile_bench.sensor.optics import SimOptics, surface_normals

CHARS = ("A", "Y", "#")


@pytest.fixture(scope="module")
def bank() -> HeightFieldBank:
    return build_bank(CHARS)


def _pose(label: int = 0, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, press: float = 0.5):
    return Poses(labels=[label], x_mm=[x], y_mm=[y], yaw_deg=[yaw], press_mm=[press])


def _sample(bank: HeightFieldBank, label: int, x: float, y: float) -> float:
    """Height at the grid node nearest to (x, y) (row 0 is +y)."""
    res, half = bank.resolution_mm, bank.half_extent_mm
    j, i = round((x + half) / res), round((half - y) / res)
    return float(bank.maps[label, 0, i, j])


def test_dot_peaks_at_dome_height_at_the_cell_positions(bank: HeightFieldBank) -> None:
    spec = BrailleSpec()
    all_dots = dot_positions("Y").tolist() + dot_positions("#").tolist()
    for label, char in enumerate(CHARS):
        raised = [tuple(p) for p in dot_positions(char)]
        for x, y in raised:
            assert _sample(bank, label, x, y) == pytest.approx(spec.dot_height_mm, abs=2e-3)
        for x, y in {tuple(p) for p in all_dots} - set(raised):
            assert _sample(bank, label, x, y) == pytest.approx(0.0, abs=1e-6)
        assert _sample(bank, label, 0.0, 0.0) == pytest.approx(0.0, abs=1e-6)  # flat top
        assert _sample(bank, label, 10.8, -10.8) == bank.far_mm == -spec.block_height_mm
    torch.testing.assert_close(
        bank.top_max, torch.full((3,), spec.dot_height_mm), atol=2e-3, rtol=0
    )


def test_bank_cache_round_trip_and_corruption(bank, tmp_path, monkeypatch) -> None:
    path = tmp_path / "bank.npz"
    bank.save(path)

    def no_raycast(*args, **kwargs):
        raise AssertionError("the cache should have been used")

    with monkeypatch.context() as m:
        m.setattr(heightfield, "raycast_heights", no_raycast)
        cached = build_bank(CHARS, cache_path=path)
    torch.testing.assert_close(cached.maps, bank.maps)
    assert cached.chars == CHARS and cached.spec == bank.spec
    path.write_bytes(b"not an npz")
    with pytest.raises(TactileBenchError, match="bank.npz"):
        HeightFieldBank.load(path)


def test_max_penetration_equals_press(bank: HeightFieldBank) -> None:
    gel = GelSpec()
    for press in (0.3, 0.9):
        poses = Poses(
            labels=[0, 1, 2], x_mm=[0, 2, -1], y_mm=[0, -3, 1], yaw_deg=[0, 45, -25],
            press_mm=[press] * 3,
        )  # fmt: skip
        height = render_height(bank, poses, gel)
        assert height.shape == (3, 1, 128, 128)
        peak = height.flatten(1).amax(1)
        # sample points miss the apex by < 0.1 mm: the dome drops < 5 um there
        torch.testing.assert_close(peak, torch.full((3,), press), atol=5e-3, rtol=0)
        depth = to_depth(height, gel)
        assert depth.shape == (3, 1, 64, 64) and depth.min() >= 0
        assert (depth.flatten(1).amax(1) <= press + 1e-6).all()
        assert (depth.flatten(1).amax(1) > press - 0.05).all()
        # the flat top stays clear of the gel: it sits dome - press below it
        assert height.flatten(1).median(1).values.max() < 0


def test_image_reads_like_the_block_from_above(bank: HeightFieldBank) -> None:
    """'A' is dot 1, top-left of the cell: its blob sits left of and above the centre."""
    gel = GelSpec()
    depth = to_depth(render_height(bank, _pose(0), gel), gel)[0, 0]
    rows, cols = torch.nonzero(depth > 0, as_tuple=True)
    s = BrailleSpec().dot_spacing_mm
    x_mm = (cols.float().mean() + 0.5) * gel.width_mm / 64 - gel.width_mm / 2
    y_mm = gel.height_mm / 2 - (rows.float().mean() + 0.5) * gel.height_mm / 64
    assert x_mm == pytest.approx(-s / 2, abs=0.2) and y_mm == pytest.approx(s, abs=0.2)
    shifted = to_depth(render_height(bank, _pose(0, x=2.0), gel), gel)[0, 0]
    cols2 = torch.nonzero(shifted > 0, as_tuple=True)[1]
    assert (cols2.float().mean() - cols.float().mean()) * gel.width_mm / 64 == pytest.approx(
        2.0, abs=0.2
    )


def test_yaw_90_rotates_the_depth_map(bank: HeightFieldBank) -> None:
    gel = GelSpec(width_mm=20.0, height_mm=20.0, size=32, oversample=2)  # square pixels
    poses = Poses(labels=[1, 1], x_mm=[0, 0], y_mm=[0, 0], yaw_deg=[0, 90], press_mm=[0.7, 0.7])
    d0, d90 = to_depth(render_height(bank, poses, gel), gel)
    assert not torch.allclose(d0, torch.rot90(d0, 1, dims=(-2, -1)), atol=1e-2)  # not symmetric
    torch.testing.assert_close(d90, torch.rot90(d0, 1, dims=(-2, -1)), atol=1e-4, rtol=0)


def test_render_depth_matches_unchunked_and_checks_labels(bank: HeightFieldBank) -> None:
    gel = GelSpec(size=32)
    g = torch.Generator().manual_seed(0)
    poses = Poses(
        labels=torch.randint(0, 3, (20,), generator=g),
        x_mm=torch.rand(20, generator=g) * 6 - 3,
        y_mm=torch.rand(20, generator=g) * 6 - 3,
        yaw_deg=torch.rand(20, generator=g) * 180 - 90,
        press_mm=torch.rand(20, generator=g) * 0.6 + 0.3,
    )
    full = to_depth(render_height(bank, poses, gel), gel)
    torch.testing.assert_close(render_depth(bank, poses, gel, chunk=7), full)
    with pytest.raises(TactileBenchError):
        render_height(bank, _pose(label=3), gel)


def test_surface_normals() -> None:
    gel = GelSpec(size=16)
    flat = surface_normals(torch.zeros(1, 1, 16, 16), gel)
    torch.testing.assert_close(flat[0, :, 5, 5], torch.tensor([0.0, 0.0, 1.0]))
    # a ramp rising along +x by 0.1 mm per mm: normal tilts towards -x
    x = (torch.arange(16) + 0.5) * gel.width_mm / 16
    ramp = surface_normals((0.1 * x).expand(1, 1, 16, 16).clone(), gel)
    expected = torch.tensor([-0.1, 0.0, 1.0]) / np.sqrt(1.01)
    torch.testing.assert_close(ramp[0, :, 8, 8], expected, atol=1e-5, rtol=0)
    # and along +y (up = towards row 0) by 0.2 mm per mm: towards -y
    y = (16 - torch.arange(16) - 0.5) * gel.height_mm / 16
    ramp_y = surface_normals((0.2 * y)[:, None].expand(1, 1, 16, 16).clone(), gel)
    expected = torch.tensor([0.0, -0.2, 1.0]) / np.sqrt(1.04)
    torch.testing.assert_close(ramp_y[0, :, 8, 8], expected, atol=1e-5, rtol=0)


def test_sim_optics_lights_follow_tacto() -> None:
    lights = SimOptics().light_positions()
    angles = torch.rad2deg(torch.atan2(lights[:, 1], lights[:, 0])) % 360
    torch.testing.assert_close(angles, torch.tensor([30.0, 150.0, 270.0]), atol=1e-4, rtol=0)
    torch.testing.assert_close(lights[:, :2].norm(dim=1), torch.full((3,), 20.0))


def test_sim_render_flat_is_background_and_contact_changes_colour(bank) -> None:
    gel = GelSpec()
    optics = SimOptics()
    bg = torch.rand(3, 64, 64) * 100 + 80
    flat = optics.render(torch.zeros(2, 1, 64, 64), bg, None, gel)
    torch.testing.assert_close(flat, bg.expand(2, -1, -1, -1))
    depth = to_depth(render_height(bank, _pose(1, press=0.9), gel), gel)
    image = optics.render(depth, bg, None, gel)
    change = (image - bg).abs()
    assert change.amax() > 30  # dome slopes are clearly visible
    assert change[:, :, depth[0, 0] == 0].mean() < 2  # nothing far from the dots (blur aside)


def test_sim_render_is_seeded() -> None:
    optics = SimOptics()
    depth = torch.zeros(4, 1, 32, 32)
    depth[:, :, 10:20, 10:20] = 0.5
    bg = torch.full((3, 32, 32), 128.0)

    def render(seed: int) -> torch.Tensor:
        return optics.render(depth, bg, torch.Generator().manual_seed(seed))

    a, b, c = render(1), render(1), render(2)
    assert torch.equal(a, b)
    assert not torch.equal(a, c)
    # the difference is pure noise: std 7 * sqrt(2)
    assert (a - c).std().item() == pytest.approx(7 * np.sqrt(2), rel=0.05)
    assert a.min() >= 0 and a.max() <= 255
