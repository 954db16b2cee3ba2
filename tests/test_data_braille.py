"""The braille data sets: builder sizes, disjoint stratified draws, save/load."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tactile_bench.data.braille import SECOND_UNIT_SET, BrailleSet, build_braille_sets
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry import Poses
from tactile_bench.sensor.depth import GelSpec, render_height, to_depth
from tactile_bench.sensor.heightfield import HeightFieldBank, build_bank
from tactile_bench.sensor.optics import SimOptics

CHARS = ("A", "B", "C")
GEL = GelSpec(size=16, oversample=1)


class BlurrySensor:
    """A stand-in real sensor: a warmer background, a blurred and brighter indentation."""

    def background(self, size: int) -> torch.Tensor:
        ramp = torch.linspace(90, 150, size)
        return torch.stack([ramp.expand(size, size), torch.full((size, size), 110.0),
                            ramp[:, None].expand(size, size)])  # fmt: skip

    def render(self, bank, poses, gel, generator):
        depth = to_depth(render_height(bank, poses, gel), gel)
        blurred = F.avg_pool2d(depth, 3, stride=1, padding=1, count_include_pad=False)
        noise = torch.randn(len(poses), 3, gel.size, gel.size, generator=generator)
        return (self.background(gel.size) + 60 * blurred + 3 * noise).clamp(0, 255)


@pytest.fixture(scope="module")
def bank() -> HeightFieldBank:
    return build_bank(CHARS)


@pytest.fixture(scope="module")
def sets(bank) -> dict[str, BrailleSet]:
    return _build(bank, seed=3)


def _build(bank: HeightFieldBank, seed: int, **kw) -> dict[str, BrailleSet]:
    kw = {"n_finetune": 12, "n_test": 7, "n_classifier_test": 10, **kw}
    bg = torch.full((3, GEL.size, GEL.size), 128.0)
    return build_braille_sets(
        bank, GEL, SimOptics(), bg, BlurrySensor(), seed=seed, chars=CHARS, progress=False, **kw
    )


def _rows(poses: Poses) -> set[tuple]:
    return set(zip(*(t.tolist() for t in poses.to_dict().values()), strict=True))


def test_builder_sizes_and_stratification(sets) -> None:
    sizes = {k: len(v) for k, v in sets.items()}
    assert sizes == {"finetune": 12, "test": 7, "classifier": 1188, "classifier_test": 10}
    assert torch.bincount(sets["finetune"].labels).tolist() == [4, 4, 4]
    counts = torch.bincount(sets["test"].labels, minlength=3)
    assert counts.sum() == 7 and counts.max() - counts.min() <= 1
    assert (torch.bincount(sets["classifier"].labels) == 396).all()
    s = sets["test"]
    assert s.depth.shape == (7, 1, 16, 16) and s.depth.dtype == torch.float32
    assert s.sim.shape == s.real.shape == (7, 3, 16, 16) and s.sim.dtype == torch.uint8
    assert s.sim_background.shape == (3, 16, 16) and s.real_background.dtype == torch.uint8
    assert torch.equal(s.labels, s.poses.labels)


def test_finetune_and_test_are_disjoint_grid_contacts(sets) -> None:
    ft, te = _rows(sets["finetune"].poses), _rows(sets["test"].poses)
    assert len(ft) == 12 and len(te) == 7 and not ft & te
    assert {x for _, x, *_ in ft | te} <= {-5.0, 0.0, 5.0}
    assert {r[3] for r in ft | te} <= {-90.0, -45.0, 0.0, 45.0, 90.0}


def test_depth_is_the_sim_depth_and_images_differ(sets, bank) -> None:
    s = sets["finetune"]
    expected = to_depth(render_height(bank, s.poses, GEL), GEL)
    torch.testing.assert_close(s.depth, expected)
    fg_sim, fg_real = s.foreground("sim"), s.foreground("real")
    assert fg_sim.dtype == torch.float32 and fg_sim.shape == (12, 3, 16, 16)
    assert abs(fg_sim.mean().item() - 0.5) < 0.05  # mostly background
    assert not torch.allclose(fg_sim, fg_real, atol=0.02)
    with pytest.raises(TactileBenchError):
        s.foreground("depth")  # type: ignore[arg-type]


def test_builder_is_seeded(bank, sets) -> None:
    again = _build(bank, seed=3)
    other = _build(bank, seed=4)
    assert torch.equal(again["test"].sim, sets["test"].sim)
    assert torch.equal(again["test"].real, sets["test"].real)
    assert _rows(again["finetune"].poses) == _rows(sets["finetune"].poses)
    assert _rows(other["finetune"].poses) != _rows(sets["finetune"].poses)
    assert not torch.equal(other["classifier"].sim, sets["classifier"].sim)  # other noise


def test_builder_rejects_impossible_requests(bank) -> None:
    with pytest.raises(TactileBenchError, match="requested"):
        _build(bank, seed=0, n_finetune=3 * 150, n_test=3 * 40)
    with pytest.raises(TactileBenchError, match="bank holds"):
        build_braille_sets(bank, GEL, SimOptics(), torch.zeros(3, 16, 16), BlurrySensor(),
                           seed=0, chars=("A", "B"), progress=False)  # fmt: skip


def test_save_load_round_trip_and_subset(sets, tmp_path) -> None:
    s = sets["test"]
    path = s.save(tmp_path / "test.npz")
    back = BrailleSet.load(path)
    for name in ("depth", "sim", "real", "labels", "sim_background", "real_background"):
        assert torch.equal(getattr(back, name), getattr(s, name)), name
    assert _rows(back.poses) == _rows(s.poses)
    assert [p.name for p in tmp_path.iterdir()] == ["test.npz"]  # no temp file left behind
    sub = back.subset(torch.tensor([1, 3]))
    assert len(sub) == 2 and torch.equal(sub.sim[1], s.sim[3])
    assert torch.equal(sub.sim_background, s.sim_background)


def test_corrupt_or_missing_file_is_a_one_line_error(sets, tmp_path) -> None:
    good = sets["finetune"].save(tmp_path / "good.npz")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"\x00" * 100)
    for path in (truncated, garbage, tmp_path / "missing.npz"):
        with pytest.raises(TactileBenchError, match=path.name):
            BrailleSet.load(path)


def test_classifier_test_contacts_are_upright_and_off_grid(sets) -> None:
    test, grid = sets["classifier_test"].poses, sets["classifier"].poses
    counts = torch.bincount(test.labels, minlength=3)
    assert counts.sum() == 10 and counts.max() - counts.min() <= 1
    assert test.x_mm.abs().max() <= 3.0 and test.y_mm.abs().max() <= 3.0
    assert test.yaw_deg.abs().max() <= 25.0
    assert test.press_mm.min() >= 0.3 and test.press_mm.max() <= 0.9
    assert not _rows(test) & _rows(grid)


class OtherUnit(BlurrySensor):
    """A second stand-in unit: a cooler background and a dimmer indentation."""

    def background(self, size: int) -> torch.Tensor:
        return super().background(size).flip(0) - 10

    def render(self, bank, poses, gel, generator):
        return (super().render(bank, poses, gel, generator) * 0.8).clamp(0, 255)


def test_second_unit_renders_the_classifier_test_contacts_and_changes_no_other_set(
    bank, sets
) -> None:
    both = _build(bank, seed=3, second_unit=OtherUnit())
    assert list(both) == [*sets, SECOND_UNIT_SET]
    for name, s in sets.items():  # byte-identical: its streams are not the others'
        for key in ("depth", "sim", "real", "labels", "sim_background", "real_background"):
            assert torch.equal(getattr(both[name], key), getattr(s, key)), (name, key)
    first, second = sets["classifier_test"], both[SECOND_UNIT_SET]
    assert _rows(second.poses) == _rows(first.poses)
    assert torch.equal(second.depth, first.depth) and torch.equal(second.sim, first.sim)
    assert torch.equal(second.real_background, OtherUnit().background(16).to(torch.uint8))
    assert (second.real.float() - first.real.float()).abs().mean() > 5  # another unit's images


def test_an_unset_second_unit_leaves_the_stage_cache_key_as_it_was() -> None:
    from tactile_bench.pipeline.stages.braille_data import BrailleDataConfig

    assert "second_unit" not in BrailleDataConfig().model_dump(mode="json")
    assert BrailleDataConfig(second_unit="digit-b").model_dump(mode="json")["second_unit"] == (
        "digit-b"
    )
