"""Paired layout frames that are not S x S: a DIGIT's 240 x 320, a GelSight's 4:3, --size."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tactile_bench.cli import main
from tactile_bench.diagnose.paired import load_paired
from tactile_bench.errors import TactileBenchError


def _write_layout(root: Path, w: int, h: int, n: int = 3, seed: int = 0) -> dict[str, np.ndarray]:
    """``n`` unlabelled w x h pairs (one round dent each) written as the paired layout."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    for part in ("depth", "sim", "real"):
        (root / part).mkdir(parents=True)
    arrays: dict[str, np.ndarray] = {}
    for i in range(n):
        r2 = (yy - h / 2) ** 2 + (xx - w / 2 - 4 * i) ** 2
        um = np.clip(600 - r2 * 3, 0, None).astype(np.uint16)  # micrometres
        Image.fromarray(um).save(root / "depth" / f"p{i}.png")
        sim = rng.integers(30, 220, (h, w, 3), dtype=np.uint8)
        Image.fromarray(sim).save(root / "sim" / f"p{i}.png")
        Image.fromarray(sim // 2 + 40).save(root / "real" / f"p{i}.png")
        arrays[f"depth{i}"], arrays[f"sim{i}"] = um, sim
    Image.fromarray(np.full((h, w, 3), 120, np.uint8)).save(root / "background.png")
    return arrays


def test_a_digit_frame_is_area_resized_to_a_square(tmp_path: Path) -> None:
    arrays = _write_layout(tmp_path, 48, 64)  # portrait 3:4, a DIGIT's 18 x 24 mm view
    data = load_paired(tmp_path)
    assert data.size == 48 and tuple(data.depth.shape[-2:]) == (48, 48)
    assert tuple(data.sim.shape[-2:]) == (48, 48) and tuple(data.background.shape) == (3, 48, 48)
    # frames stay 8-bit levels, as a camera that stored them at 48 x 48 would have them
    assert bool((data.sim == data.sim.round()).all()) and float(data.sim.max()) <= 255
    # area averaging keeps the mean penetration and the mean colour (Pillow's box filter
    # weighs a pixel split between two new ones by sampling: to 0.1%)
    order = [int(name[1:]) for name in data.names]
    for got, i in zip(data.depth, order, strict=True):
        assert float(got.mean()) == pytest.approx(arrays[f"depth{i}"].mean() / 1000, rel=5e-3)
    for got, i in zip(data.sim, order, strict=True):
        assert float(got.mean()) == pytest.approx(arrays[f"sim{i}"].mean(), abs=0.5)


def test_size_resizes_square_frames_too(tmp_path: Path) -> None:
    _write_layout(tmp_path, 64, 64)
    assert load_paired(tmp_path).size == 64  # square frames up to 64 are kept as they are
    assert load_paired(tmp_path, size=32).size == 32
    assert load_paired(tmp_path, size=80).size == 80  # larger: the box filter too


def test_square_frames_above_64_come_down_to_the_validated_size(tmp_path: Path) -> None:
    _write_layout(tmp_path, 96, 96)
    assert load_paired(tmp_path).size == 64
    assert load_paired(tmp_path, size=96).size == 96


def test_a_frame_across_the_gel_view_is_one_line_naming_gel_json(tmp_path: Path) -> None:
    _write_layout(tmp_path, 64, 48)  # landscape frames, the default view is portrait
    with pytest.raises(TactileBenchError, match=r"64 x 48 .*18 x 24 mm.*gel\.json") as err:
        load_paired(tmp_path)
    assert "\n" not in str(err.value)
    (tmp_path / "gel.json").write_text(json.dumps({"width_mm": 24, "height_mm": 18}))
    assert load_paired(tmp_path).gel_mm == (24.0, 18.0)


@pytest.mark.parametrize("size", [4, 5000])  # the CLI refuses them the same way
def test_a_size_out_of_range_is_refused(tmp_path: Path, size: int) -> None:
    _write_layout(tmp_path, 32, 32)
    with pytest.raises(TactileBenchError, match=f"--size: must be between 16 and 4096, got {size}"):
        load_paired(tmp_path, size=size)


def test_diagnose_runs_on_digit_shaped_frames(tmp_path: Path) -> None:
    _write_layout(tmp_path / "pairs", 48, 64, n=8)
    out = tmp_path / "out"
    args = ["diagnose", str(tmp_path / "pairs"), "--out", str(out), "--no-downstream"]
    assert main([*args, "--no-progress", "--candidates", "vignetting"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["n_pairs"] == 8 and report["size"] == 48


def test_a_renderer_and_a_camera_at_different_sizes_meet_at_the_smaller(tmp_path: Path) -> None:
    _write_layout(tmp_path, 48, 64)  # the camera's frames
    small = _write_layout(tmp_path / "renderer", 36, 48)  # depth and sim at a renderer's size
    for i in range(3):
        for part in ("depth", "sim"):
            (tmp_path / "renderer" / part / f"p{i}.png").replace(tmp_path / part / f"p{i}.png")
    data = load_paired(tmp_path)
    assert data.size == 36 and tuple(data.real.shape[-2:]) == (36, 36)
    order = [int(name[1:]) for name in data.names]
    for got, i in zip(data.depth, order, strict=True):  # the renderer's depth, box-filtered
        assert float(got.mean()) == pytest.approx(small[f"depth{i}"].mean() / 1000, rel=5e-3)
    # the measured no-contact frame is the camera's: at the sim's size it is refused
    Image.fromarray(np.zeros((48, 36, 3), np.uint8)).save(tmp_path / "background.png")
    with pytest.raises(TactileBenchError, match=r"background\.png: is 36 x 48, the other"):
        load_paired(tmp_path)
