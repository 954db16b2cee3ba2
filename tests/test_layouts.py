"""Loaders for the original releases' layouts, on fixtures generated in those layouts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from data.make_layouts import make_braille_layout, make_ycb_slide_real

from tactile_bench.data.tactile_diffusion import load_braille_pairs, load_braille_real_images
from tactile_bench.data.ycb_real import jump_mask, load_ycb_slide_real
from tactile_bench.errors import TactileBenchError

OBJ = "004_sugar_box"


@pytest.fixture
def ycb(tmp_path: Path) -> Path:
    make_ycb_slide_real(tmp_path, OBJ, n_frames=5, datasets=2)
    return tmp_path


def test_ycb_slide_real_pairs(ycb: Path) -> None:
    pairs = load_ycb_slide_real(ycb)
    assert len(pairs) == 10 and pairs.depth.shape == (10, 1, 64, 64)
    assert pairs.real.shape == (10, 3, 64, 64) and pairs.real.dtype == torch.uint8
    # the gel lies flat on the box's top face, pressed 0.7 mm: uniform depth
    assert torch.allclose(pairs.depth, torch.full_like(pairs.depth, 0.7), atol=1e-3)
    assert len(pairs.real_background) == 2 and set(pairs.meta["trajectory"]) == {0, 1}
    assert pairs.foreground().shape == (10, 3, 64, 64)


def test_ycb_slide_real_stride_and_press(ycb: Path) -> None:
    pairs = load_ycb_slide_real(ycb, stride=2, press_mm=0.4)
    assert len(pairs) == 6 and list(pairs.meta["frame"][:3]) == [0, 2, 4]
    assert torch.allclose(pairs.depth, torch.full_like(pairs.depth, 0.4), atol=1e-3)


def test_mocap_jumps_are_dropped() -> None:
    # YCB-Slide's rule: a step > 10x the running mean step (the step itself included) is a jump
    x = np.arange(24, dtype=float)
    x[21] = 70.0
    poses = np.tile(np.eye(4), (24, 1, 1))
    poses[:, 0, 3] = x
    keep = jump_mask(poses)
    assert not keep[21] and keep[:21].all() and keep[22:].all()


def test_ycb_slide_errors_name_the_file(ycb: Path) -> None:
    log = ycb / "real" / OBJ / "dataset_0"
    frame = log / "frames" / "frame_0000002.jpg"
    frame.write_bytes(b"not a jpeg")
    with pytest.raises(TactileBenchError, match="frame_0000002.jpg"):
        load_ycb_slide_real(ycb)
    frame.unlink()
    with pytest.raises(TactileBenchError, match="4 frames but 5 poses"):
        load_ycb_slide_real(ycb)
    for f in (log / "frames").iterdir():
        f.unlink()
    with pytest.raises(TactileBenchError, match="no frame_"):
        load_ycb_slide_real(ycb)


@pytest.mark.parametrize("case", ["missing", "shape", "nan", "key"])
def test_ycb_slide_bad_poses(ycb: Path, case: str) -> None:
    synced = ycb / "real" / OBJ / "dataset_1" / "synced_data.npy"
    data = np.load(synced, allow_pickle=True).item()
    if case == "missing":
        synced.unlink()
    elif case == "shape":
        data["poses"]["DIGIT"] = data["poses"]["DIGIT"][:, :6]
        np.save(synced, data)
    elif case == "nan":
        data["poses"][OBJ][1, 0] = np.nan
        np.save(synced, data)
    else:
        del data["poses"][OBJ]
        np.save(synced, data)
    with pytest.raises(TactileBenchError, match="synced_data.npy"):
        load_ycb_slide_real(ycb)


def test_ycb_slide_missing_mesh_alignment_folder(
    ycb: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    (ycb / "real" / OBJ / "alignment.npy").unlink()
    with pytest.raises(TactileBenchError, match="alignment.npy"):
        load_ycb_slide_real(ycb)
    (ycb / "obj_models" / OBJ / "nontextured.stl").unlink()
    with pytest.raises(TactileBenchError, match="nontextured.stl"):
        load_ycb_slide_real(ycb)
    with pytest.raises(TactileBenchError, match="real"):
        load_ycb_slide_real(tmp_path_factory.mktemp("empty"))


@pytest.fixture
def braille(tmp_path: Path) -> Path:
    make_braille_layout(tmp_path, letters=("a", "b", "#"), per_letter=3, level=20)
    return tmp_path


def test_braille_pairs_split(braille: Path) -> None:
    train = load_braille_pairs(braille, "train")
    test = load_braille_pairs(braille, "test")
    both = load_braille_pairs(braille, "all")
    assert (len(train), len(test), len(both)) == (6, 3, 9)
    assert torch.allclose(train.depth, torch.full_like(train.depth, 20 * 0.03))
    assert sorted(set(train.meta["label"].tolist())) == [0, 1, 26]  # a, b, #
    assert train.real.shape == (6, 3, 64, 64)
    assert torch.all(train.real_background == 128)


def test_braille_real_images(braille: Path) -> None:
    images, labels, bg = load_braille_real_images(braille)
    assert (
        images.shape == (9, 3, 64, 64)
        and labels.tolist().count(26) == 3
        and bg.shape == (3, 64, 64)
    )


def test_braille_errors_name_the_file(braille: Path) -> None:
    mask = braille / "real_fine_tuning" / "mask" / "a" / "a_0.png"
    mask.write_bytes(b"\x89PNG garbage")
    with pytest.raises(TactileBenchError, match="a_0.png"):
        load_braille_pairs(braille, "train")
    mask.unlink()
    with pytest.raises(TactileBenchError, match="a_0.png: file not found"):
        load_braille_pairs(braille, "train")
    with pytest.raises(TactileBenchError, match="split must be"):
        load_braille_pairs(braille, "val")
    (braille / "real_fine_tuning" / "files_train_test.npy").write_bytes(b"junk")
    with pytest.raises(TactileBenchError, match="files_train_test.npy"):
        load_braille_pairs(braille, "test")
    (braille / "bgs" / "bg_10044.png").unlink()
    with pytest.raises(TactileBenchError, match="bg_10044.png"):
        load_braille_real_images(braille)


def test_braille_empty_and_unknown_letters(tmp_path: Path) -> None:
    with pytest.raises(TactileBenchError, match="color"):
        load_braille_pairs(tmp_path)
    make_braille_layout(tmp_path, letters=("a",), per_letter=2)
    (tmp_path / "real" / "color" / "zz").mkdir()
    with pytest.raises(TactileBenchError, match="zz"):
        load_braille_real_images(tmp_path)
    for f in (tmp_path / "real_fine_tuning" / "color" / "a").iterdir():
        f.unlink()
    with pytest.raises(TactileBenchError, match="unpaired"):  # masks left without colour
        load_braille_pairs(tmp_path, "all")
    for f in (tmp_path / "real_fine_tuning" / "mask" / "a").iterdir():
        f.unlink()
    with pytest.raises(TactileBenchError, match="no 'all' images"):
        load_braille_pairs(tmp_path, "all")
