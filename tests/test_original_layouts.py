"""The real datasets as their authors publish them (fixtures from the original code's paths).

``data/original_layouts.py`` writes the Tactile-Diffusion braille release and its processed
YCB-Slide copy to the paths, names and formats the original code reads: no split file, all 27
letter folders, masks smaller than the frames and partly stored as colour. ``check`` and
``fit`` must agree on each, and the split must be made in the run, never in the dataset.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from data.original_layouts import BGS_LETTERS, write_braille_release
from PIL import Image

from tactile_bench.cli import main
from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.images import read_image, read_mask
from tactile_bench.data.tactile_diffusion import (
    braille_root,
    load_braille_pairs,
    make_split,
    read_split,
)

RECIPE = """
name: release
seed: 3
stages:
  - name: braille
    kind: braille_data
    config: {{source: {source}, n_classifier: 54, image_size: 16, sim_source: release}}
  - name: translator
    kind: fit_translator
    inputs: {{braille: braille}}
    config:
      translator: colour_match
      train_set: split_train
      eval_pairs: 8
      translator_config: {{max_steps: 1, batch_size: 8}}
  - name: translator_pool
    kind: fit_translator
    inputs: {{braille: braille}}
    config:
      translator: colour_match
      eval_pairs: 8
      translator_config: {{max_steps: 1, batch_size: 8}}
  - name: classify_sim
    kind: classify
    inputs: {{data: braille}}
    config: {{row: sim, train_images: sim, train_set: sim_release, heldout_fraction: 0.0,
              classifier: {{width: 4, epochs: 1}}}}
  - name: classify_sim_ft20
    kind: classify
    inputs: {{data: braille, init: classify_sim}}
    config: {{row: sim_ft20, train_images: sim, train_set: sim_release, heldout_fraction: 0.0,
              finetune_fraction: 0.2, finetune_epochs: 1, classifier: {{width: 4, epochs: 1}}}}
"""


def _fit(recipe: Path, run_dir: Path) -> int:
    return main(["fit", str(recipe), "--run-dir", str(run_dir), "--no-progress"])


def _stage_dirs(run_dir: Path) -> dict[str, Path]:
    stages = json.loads((run_dir / "run.json").read_text())["stages"]
    return {s["name"]: run_dir / s["directory"] for s in stages}


@pytest.fixture(scope="module")
def release(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``<tmp>/datasets/braille``; returns ``<tmp>/datasets`` (what users point at)."""
    datasets = tmp_path_factory.mktemp("release") / "datasets"
    write_braille_release(datasets)
    return datasets


@pytest.fixture(scope="module")
def fitted(release: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One fit of the recipe on the parent ``datasets`` folder; returns the run dir."""
    work = tmp_path_factory.mktemp("fit")
    recipe = work / "release.yaml"
    recipe.write_text(RECIPE.format(source=release))
    run_dir = work / "run"
    assert _fit(recipe, run_dir) == 0
    return run_dir


def test_split_is_drawn_into_the_run_not_the_dataset(
    release: Path, fitted: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    braille = release / "braille"
    assert not (braille / "real_fine_tuning" / "files_train_test.npy").exists()
    written = _stage_dirs(fitted)["braille"] / "files_train_test.npy"
    # readable the way train_braille.py reads it: dict(np.load(...).item())
    split = dict(np.load(written, allow_pickle=True).item())
    assert list(split) == list(BGS_LETTERS)
    # split_braille_dataset(0.2, 0.2) on 10 files a letter: keep 2, train int(1.6) = 1
    assert all((len(v["train"]), len(v["test"])) == (1, 1) for v in split.values())
    assert split == make_split(braille, seed=3)  # the recipe's seed, drawn again: the same
    assert not set(split["a"]["train"]) & set(split["a"]["test"])
    # check draws the split a recipe of that seed draws, and reports the same counts
    assert main(["check", str(release), "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "270 fine-tuning pairs" in out and "27 train / 27 test" in out
    assert not (braille / "real_fine_tuning" / "files_train_test.npy").exists()


def test_split_file_of_the_release_is_read_when_present(tmp_path: Path) -> None:
    datasets = tmp_path / "datasets"
    braille = write_braille_release(datasets, per_letter=10)
    split = {letter: {"train": ["0.jpg", "1.jpg", "2.jpg"], "test": ["3.jpg"]} for letter in "ab"}
    np.save(braille / "real_fine_tuning" / "files_train_test.npy", split)  # as the original
    assert read_split(braille / "real_fine_tuning" / "files_train_test.npy") == split
    assert len(load_braille_pairs(braille, "train", skipped=None)) == 6


def test_finetune_fractions_are_of_the_whole_pool(fitted: Path) -> None:
    dirs = _stage_dirs(fitted)
    finetune = BrailleSet.load(dirs["braille"] / "finetune.npz")
    split_train = BrailleSet.load(dirs["braille"] / "split_train.npz")
    assert (len(finetune), len(split_train)) == (270, 27)  # all 27 x 10 pairs; 1 a letter
    ft20 = json.loads((dirs["classify_sim_ft20"] / "metrics.json").read_text())["summary"]
    assert ft20["n_finetune"] == 54  # 20% of all 270 (braille_clf p_data_fine_tune)
    fitted_translator = json.loads((dirs["translator"] / "metrics.json").read_text())
    assert fitted_translator["fit_pairs"] == 27  # the translator trains on the split's train list
    # on the whole pool, a translator leaves out the split's test files it is scored on
    in_test = np.load(dirs["braille"] / "finetune_in_test.npy")
    assert in_test.sum() == 27
    pool = json.loads((dirs["translator_pool"] / "metrics.json").read_text())
    assert pool["fit_pairs"] == 270 - 27


def test_sim_row_trains_on_the_release_tacto_frames(fitted: Path) -> None:
    dirs = _stage_dirs(fitted)
    sim = BrailleSet.load(dirs["braille"] / "sim_release.npz")
    assert len(sim) == 27 and sim.real.max() == 0  # TACTO frames only
    # bg_11 of the fixture is (90, 100, 130): the Sim row subtracts it (braille_clf dataio)
    assert sim.sim_background[:, 0, 0].tolist() == [90, 100, 130]
    summary = json.loads((dirs["classify_sim"] / "metrics.json").read_text())["summary"]
    assert summary["n_train"] == 27 and summary["n_test"] == 27


def test_masks_are_read_as_the_original_reads_them(release: Path, tmp_path: Path) -> None:
    braille = release / "braille"
    pairs = load_braille_pairs(braille, "all")  # masks 24 x 32, frames 48 x 64: both read
    assert pairs.depth.shape == (270, 1, 64, 64) and pairs.real.shape == (270, 3, 64, 64)
    mask_dir = braille / "real_fine_tuning" / "mask" / "a"
    grey, colour = read_mask(mask_dir / "0.jpg", 64), read_mask(mask_dir / "1.jpg", 64)
    assert 19 <= grey.max() <= 21 and 20 <= colour.max() <= 22  # levels 20 and 21, JPEG'd
    # a tinted mask: cv2.imread gives B, G, R and RGB2GRAY weighs them 0.299, 0.587, 0.114
    tinted = np.zeros((4, 4, 3), np.uint8)
    tinted[..., 2] = 100  # blue in the file
    Image.fromarray(tinted).save(tmp_path / "tinted.png")
    assert read_mask(tmp_path / "tinted.png")[0, 0] == 30  # round(0.299 * 100)
    assert read_mask(tmp_path / "tinted.png", weights_bgr_as_rgb=False)[0, 0] == 11


def test_frames_not_stored_as_rgb_are_read_as_cv2_imread_reads_them(tmp_path: Path) -> None:
    # cv2.imread(path) (IMREAD_COLOR), the original loaders' reader: grey to all three
    # channels, alpha dropped without compositing, 16-bit grey to its high byte
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    grey = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    alpha = rng.integers(0, 256, (6, 8, 1), dtype=np.uint8)
    Image.fromarray(grey).save(tmp_path / "grey.png")
    Image.fromarray(np.concatenate([rgb, alpha], axis=2)).save(tmp_path / "rgba.png")
    Image.fromarray(grey.astype(np.uint16) * 257 + 3).save(tmp_path / "grey16.png")
    Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE).save(tmp_path / "p.png")
    as_hwc = {
        n: read_image(tmp_path / f"{n}.png").permute(1, 2, 0).numpy()
        for n in ("grey", "rgba", "grey16", "p")
    }
    assert np.array_equal(as_hwc["grey"], np.repeat(grey[..., None], 3, axis=2))
    assert np.array_equal(as_hwc["rgba"], rgb)
    assert np.array_equal(as_hwc["grey16"], np.repeat(grey[..., None], 3, axis=2))
    assert as_hwc["p"].shape == (6, 8, 3)


def test_check_reads_a_release_with_grey_and_rgba_frames_and_notes_each_mode_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    datasets = tmp_path / "datasets"
    write_braille_release(datasets)
    color = datasets / "braille" / "real_fine_tuning" / "color"
    for letter, mode in (("a", "L"), ("b", "L"), ("c", "RGBA")):
        for name in ("0.jpg", "1.jpg"):
            frame = Image.open(color / letter / name).convert(mode)
            frame.save(color / letter / name.replace(".jpg", ".png"))
            (color / letter / name).unlink()
            mask = datasets / "braille" / "real_fine_tuning" / "mask" / letter / name
            mask.rename(mask.with_suffix(".png"))
    assert main(["check", str(datasets)]) == 0
    err = capsys.readouterr().err
    assert err.count("mode L)") == 1 and err.count("mode RGBA)") == 1, err
    assert "cv2.imread" in err


def test_source_is_the_braille_folder_or_its_parent(release: Path, tmp_path: Path) -> None:
    assert braille_root(release) == braille_root(release / "braille") == release / "braille"
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: r\nstages:\n  - name: braille\n    kind: braille_data\n"
        f"    config: {{source: {release / 'braille'}, n_classifier: 27, image_size: 16}}\n"
    )
    assert main(["check", str(recipe)]) == 0
    recipe.write_text(recipe.read_text().replace(str(release / "braille"), str(tmp_path)))
    assert main(["check", str(recipe)]) == 2


def test_check_and_fit_fail_alike_on_a_frame_off_the_background_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    datasets = tmp_path / "datasets"
    braille = write_braille_release(datasets, per_letter=10, real_per_letter=1)
    bad = braille / "real_fine_tuning" / "color" / "b" / "3.jpg"
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(bad)
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: r\nstages:\n  - name: braille\n    kind: braille_data\n"
        f"    config: {{source: {datasets}, n_classifier: 27, image_size: 16}}\n"
    )
    capsys.readouterr()
    assert main(["check", str(datasets)]) == 2
    check_err = capsys.readouterr().err.strip().splitlines()
    assert _fit(recipe, tmp_path / "run") == 2
    fit_err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]
    assert len(check_err) == 1 and len(fit_err) == 1
    assert "3.jpg: 10 x 10 pixels" in check_err[0] and "bg_10044.png" in check_err[0]
    assert check_err[0].split("3.jpg")[1] == fit_err[0].split("3.jpg")[1]


def test_processed_ycb_copy_is_a_corpus_source(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from data.original_layouts import BGS_OBJECTS, write_ycb_processed

    from tactile_bench.data.corpus import load_pairs

    datasets = tmp_path / "datasets"
    root = write_ycb_processed(datasets, frames=6, logs=2)
    capsys.readouterr()
    assert main(["check", str(root)]) == 0
    out = capsys.readouterr().out
    # 2 objects x 2 logs x 6 frames, frame 1 of each log has no heightmap: 20 pairs, 4 test
    assert "20 (depth, frame) pairs from 4 logs (16 train / 4 test" in out
    recipe = tmp_path / "ycb.yaml"
    recipe.write_text(
        "name: ycb\nstages:\n  - name: corpus\n    kind: ycb_slide_data\n"
        f"    config: {{source: {datasets}, image_size: 16}}\n"
    )
    assert _fit(recipe, tmp_path / "run") == 0
    corpus = _stage_dirs(tmp_path / "run")["corpus"]
    train, test = load_pairs(corpus, "train"), load_pairs(corpus, "test")
    assert (len(train), len(test)) == (16, 4)
    # save_hm's levels are pixels of pixmm = 0.03 mm: the 23-level press is 0.69 mm deep
    assert abs(float(train.depth.max()) - 23 * 0.03) < 0.05
    # each object's background is its bgs_objects frame, bgs/bg_<i>.jpg
    for obj, bg_id in BGS_OBJECTS.items():
        expected = Image.open(root / "bgs" / f"bg_{bg_id}.jpg").convert("RGB").getpixel((0, 0))
        o = sorted(BGS_OBJECTS).index(obj)
        got = train.real_background[train.real_bg_index[train.meta["object"] == o][0]]
        assert np.abs(got[:, 0, 0].numpy().astype(int) - np.array(expected)).max() <= 2
    # depth and frame lie the same way: the press is where the frame differs from its bg
    # (save_hm flipped TACTO's map once; a second flip here would put it upside down)
    diff = train.foreground("real").sub(0.5).sum(1).flatten(1)
    as_read, flipped = train.depth[:, 0].flatten(1), train.depth[:, 0].flip(1, 2).flatten(1)

    def corr(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        a, b = a - a.mean(1, keepdim=True), b - b.mean(1, keepdim=True)
        return (a * b).sum(1) / (a.norm(dim=1) * b.norm(dim=1))

    assert bool((corr(as_read, diff) > 0.5).all())
    assert bool((corr(as_read, diff) > corr(flipped, diff) + 0.3).all())


def test_processed_ycb_copy_without_its_split_files_gets_one_drawn_into_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As ``get_train_test_idx`` writes it: per log, int(n x 0.2) of the frames test, the
    rest train, from the recipe's seed; written in the stage folder, never into the copy."""
    from data.original_layouts import write_ycb_processed

    from tactile_bench.data.corpus import load_pairs
    from tactile_bench.data.ycb_processed import SPLIT_FILE, make_log_split

    datasets = tmp_path / "datasets"
    root = write_ycb_processed(datasets, frames=6, logs=2)
    for split in root.glob(f"dataset/*/*/{SPLIT_FILE}"):
        split.unlink()
    capsys.readouterr()
    assert main(["check", str(root)]) == 0
    out = capsys.readouterr().out
    # 2 objects x 2 logs x 6 frames, one test frame a log (int(6 x 0.2)); frame 1 has no
    # heightmap, so 20 pairs, of which 4 test unless frame 1 was drawn as a log's test frame
    assert "20 (depth, frame) pairs from 4 logs" in out
    assert "split: generated for 4 of 4 logs (seed 0, test 0.2)" in out
    recipe = tmp_path / "ycb.yaml"
    recipe.write_text(
        "name: ycb\nseed: 3\nstages:\n  - name: corpus\n    kind: ycb_slide_data\n"
        f"    config: {{source: {datasets}, image_size: 16}}\n"
    )
    assert _fit(recipe, tmp_path / "run") == 0
    assert not list(root.glob(f"dataset/*/*/{SPLIT_FILE}"))  # the copy is left as it was
    corpus = _stage_dirs(tmp_path / "run")["corpus"]
    written = sorted((corpus / "splits").glob(f"*/*/{SPLIT_FILE}"))
    assert len(written) == 4
    n_test = 0
    for path in written:
        log = root / "dataset" / path.parent.parent.name / path.parent.name
        with np.load(path) as z:  # the original's reader: np.load(...)["train"], ["test"]
            train, test = z["train"].tolist(), z["test"].tolist()
        assert (train, test) == make_log_split(log, seed=3)
        assert len(test) == 1 and sorted(train + test) == sorted(
            f.name for f in (log / "frames").glob("*.jpg")
        )
        n_test += test != ["frame_0000001.jpg"]  # frame 1 has no heightmap: not a pair
    assert len(load_pairs(corpus, "test")) == n_test
    # the seed draws: other seeds pick other test frames
    assert len({tuple(make_log_split(log, seed)[1]) for seed in range(10)}) > 1


def test_ycb_slide_release_backgrounds_are_used_when_present(tmp_path: Path) -> None:
    from data.make_layouts import make_ycb_slide_real

    from tactile_bench.data.ycb_real import load_ycb_slide_real

    make_ycb_slide_real(tmp_path, "004_sugar_box", n_frames=3, datasets=1)
    first = load_ycb_slide_real(tmp_path, snap_to_surface=False)  # no bgs/: first frame
    (tmp_path / "bgs").mkdir()
    Image.fromarray(np.full((320, 240, 3), 77, np.uint8)).save(tmp_path / "bgs" / "bg_0.jpg")
    released = load_ycb_slide_real(tmp_path, snap_to_surface=False)
    assert int(released.real_background.float().mean().round()) == 77
    assert not torch.equal(first.real_background, released.real_background)
    assert torch.equal(first.depth, released.depth)
