"""Braille cells, block meshes and the paper's contact protocols."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry import (
    BRAILLE_DOTS,
    CHARACTERS,
    PRESS_DEPTHS_MM,
    BrailleSpec,
    Poses,
    braille_mesh,
    classifier_protocol,
    dot_positions,
    finetune_test_protocol,
)


@pytest.mark.parametrize(
    ("char", "count"), [("A", 1), ("B", 2), ("C", 2), ("L", 3), ("W", 4), ("Y", 5), ("#", 4)]
)
def test_dot_counts(char: str, count: int) -> None:
    assert len(BRAILLE_DOTS[char]) == count
    assert dot_positions(char).shape == (count, 2)


def test_patterns_cover_the_paper_and_are_distinct() -> None:
    assert len(CHARACTERS) == 27 and CHARACTERS[-1] == "#"
    assert set(BRAILLE_DOTS) == set(CHARACTERS)
    assert len({BRAILLE_DOTS[c] for c in CHARACTERS}) == 27
    assert BRAILLE_DOTS["#"] == frozenset({3, 4, 5, 6})
    assert all(d <= {1, 2, 3, 4, 5, 6} and d for d in BRAILLE_DOTS.values())


def test_dot_positions_follow_the_cell_layout() -> None:
    s = BrailleSpec().dot_spacing_mm
    # A is dot 1: top-left; # has dot 3 (bottom-left) and 4, 5, 6 (right column).
    np.testing.assert_allclose(dot_positions("A"), [[-s / 2, s]])
    np.testing.assert_allclose(
        dot_positions("#"), [[-s / 2, -s], [s / 2, s], [s / 2, 0.0], [s / 2, -s]]
    )


@pytest.mark.parametrize("char", ["A", "Y", "#"])
def test_mesh_is_watertight_with_expected_bounds_and_volume(char: str) -> None:
    spec = BrailleSpec()
    mesh = braille_mesh(char, spec)
    assert mesh.is_watertight and mesh.is_winding_consistent
    top = spec.block_height_mm + spec.dot_height_mm
    np.testing.assert_allclose(mesh.bounds, [[-10, -10, 0], [10, 10, top]], atol=1e-9)
    h, r = spec.dot_height_mm, spec.sphere_radius_mm
    cap = math.pi * h * h * (3 * r - h) / 3
    expected = 20 * 20 * 10 + len(BRAILLE_DOTS[char]) * cap
    assert mesh.volume == pytest.approx(expected, rel=1e-3)  # positive: normals point out


def test_unknown_character_is_an_error() -> None:
    with pytest.raises(TactileBenchError, match="unknown braille character"):
        braille_mesh("a")
    with pytest.raises(TactileBenchError):
        dot_positions("?")
    with pytest.raises(TactileBenchError):
        finetune_test_protocol(("A", "?"))


def test_spec_rejects_impossible_dimensions() -> None:
    with pytest.raises(TactileBenchError):
        BrailleSpec(dot_base_diameter_mm=6.0)
    with pytest.raises(TactileBenchError):
        BrailleSpec(dot_height_mm=3.0)


def _per_char_counts(poses: Poses) -> torch.Tensor:
    return torch.bincount(poses.labels, minlength=len(CHARACTERS))


def test_finetune_test_protocol() -> None:
    p = finetune_test_protocol()
    assert len(p) == 180 * 27
    assert (_per_char_counts(p) == 180).all()
    assert sorted(p.x_mm.unique().tolist()) == [-5.0, 0.0, 5.0]
    assert sorted(p.y_mm.unique().tolist()) == [-5.0, 0.0, 5.0]
    assert sorted(p.yaw_deg.unique().tolist()) == [-90.0, -45.0, 0.0, 45.0, 90.0]
    assert len(p.press_mm.unique()) == 4
    assert p.labels.dtype == torch.int64 and p.x_mm.dtype == torch.float32
    rows = set(zip(*(t.tolist() for t in p.to_dict().values()), strict=True))
    assert len(rows) == len(p)  # every contact is distinct


def test_classifier_protocol() -> None:
    p = classifier_protocol()
    assert len(p) == 396 * 27
    assert (_per_char_counts(p) == 396).all()
    assert sorted(p.x_mm.unique().tolist()) == [-3.0, 0.0, 3.0]
    assert sorted(p.yaw_deg.unique().tolist()) == [float(y) for y in range(-25, 26, 5)]


def test_press_depths_touch_with_the_dots_only() -> None:
    assert len(PRESS_DEPTHS_MM) == 4
    assert min(PRESS_DEPTHS_MM) > 0 and max(PRESS_DEPTHS_MM) < BrailleSpec().dot_height_mm


def test_poses_index_and_cat() -> None:
    p = classifier_protocol(("A", "B"))
    sub = p.index(torch.tensor([0, 400, 791]))
    assert sub.labels.tolist() == [0, 1, 1]
    mask = p.labels == 1
    assert len(p.subset(mask)) == 396
    assert len(Poses.cat([sub, p.index(slice(0, 5))])) == 8
    with pytest.raises(TactileBenchError):
        Poses(labels=[0, 1], x_mm=[0.0], y_mm=[0.0, 0.0], yaw_deg=[0.0, 0.0], press_mm=[0, 0])
