"""The kinds of bad input scripts/bad_inputs.py feeds the command line (one ``Case`` each).

Each case builds its bad input under a temporary folder and returns the CLI arguments that
read it, and names what the error line must mention (the file or key at fault).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from bad_input_fixtures import (
    BRAILLE_STAGE,
    braille_layout,
    cgan_from,
    corpus,
    file_sha256,
    fit_args,
    frame,
    paired_layout,
    plugin_env,
    png,
    translator_checkpoint,
    ycb_layout,
    ycb_recipe,
)
from bad_input_guard_cases import GUARD_CASES
from PIL import Image


# ----------------------------------------------------------------------------- cases
@dataclass
class Case:
    """One kind of bad input: how to build it (returns CLI args) and what the error must name."""

    kind: str
    build: Callable[[Path], list[str]]
    names: str  # the error line must contain this (the file or key at fault)
    expect_exit: int = 2
    env: Callable[[Path], dict[str, str]] | None = None
    slow: bool = False  # renders meshes or runs stages: left out of the in-process test
    group: str = "files and layouts"  # the class of bad input (issue 23's classes, ...)


def _td(tmp: Path) -> Path:
    return braille_layout(tmp / "td")


def c_corrupt_png(tmp: Path) -> list[str]:
    root = _td(tmp)
    (root / "real_fine_tuning/color/a/a_0.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    return ["check", str(root)]


def c_truncated_png(tmp: Path) -> list[str]:
    root = _td(tmp)
    f = root / "real_fine_tuning/color/b/b_1.png"
    f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])
    return ["check", str(root)]


def c_truncated_jpeg(tmp: Path) -> list[str]:
    root = ycb_layout(tmp / "ycb")
    f = root / "real/004_sugar_box/dataset_0/frames/frame_0000002.jpg"
    f.write_bytes(f.read_bytes()[:300])
    return ["check", str(root)]


def c_wrong_size(tmp: Path) -> list[str]:
    root = _td(tmp)
    png(root / "real/color/b/b_0.png", frame(3, (160, 120)))
    return ["check", str(root)]


# The released layouts' frames are read as cv2.imread reads them (grey to three channels,
# alpha dropped), so a grey or RGBA frame there is data, not an error; the diagnosis's own
# paired layout is documented as 8-bit RGB and refuses them.
def c_rgba(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    rgba = np.dstack([frame(4, (32, 32)), np.full((32, 32), 255, np.uint8)])
    png(root / "real" / "c1.png", rgba)
    return ["diagnose", str(root), "--out", str(tmp / "out"), "--no-progress"]


def c_grey_frame(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png(root / "sim" / "c1.png", frame(5, (32, 32))[..., 0])
    return ["diagnose", str(root), "--out", str(tmp / "out"), "--no-progress"]


def c_truncated_mask(tmp: Path) -> list[str]:
    # a colour or 16-bit mask is read as the original reads it (cv2.imread, then grey); a
    # mask cut short fails there too (cv2.imread gives None)
    root = _td(tmp)
    f = root / "real_fine_tuning/mask/b/b_0.png"
    f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])
    return ["check", str(root)]


def c_frame_off_background(tmp: Path) -> list[str]:
    # the original subtracts bg_10044.png at full size (compute_diff), which fails
    root = _td(tmp)
    png(root / "real_fine_tuning/color/a/a_0.png", frame(6, (160, 120)))
    return ["check", str(root)]


def c_empty_folder(tmp: Path) -> list[str]:
    root = tmp / "td"
    for sub in ("real_fine_tuning/color/a", "real_fine_tuning/mask/a", "bgs"):
        (root / sub).mkdir(parents=True)
    return ["check", str(root)]


def c_unpaired(tmp: Path) -> list[str]:
    root = _td(tmp)
    png(root / "real_fine_tuning/color/b/b_extra.png", frame(7))
    return ["check", str(root)]


def c_unknown_label(tmp: Path) -> list[str]:
    root = _td(tmp)
    for sub in ("real_fine_tuning/color", "real_fine_tuning/mask"):
        png(root / sub / "zz" / "z_0.png", frame(8) if "color" in sub else frame(8)[..., 0])
    return ["check", str(root)]


def c_bad_split(tmp: Path) -> list[str]:
    root = _td(tmp)
    (root / "real_fine_tuning/files_train_test.npy").write_bytes(b"\x93NUMPY garbage")
    return ["check", str(root)]


def c_paired_wrong_size(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png(root / "real" / "c1.png", frame(3, (20, 20)))
    return ["diagnose", str(root), "--out", str(tmp / "out"), "--no-progress"]


def c_paired_unpaired(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    (root / "real" / "c0.png").unlink()
    return ["diagnose", str(root), "--out", str(tmp / "out"), "--no-progress"]


def _bad_shard(tmp: Path, value: float) -> list[str]:
    root = corpus(tmp / "corpus")
    shard = root / "shards" / "0_1.npz"
    with np.load(shard) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["depth"][0, 0, 3, 3] = value
    np.savez(shard, **arrays)
    # a corpus someone built with bad values: its manifest hashes match, the values do not
    manifest = json.loads((root / "manifest.json").read_text())
    for entry in manifest["shards"]:
        entry["sha256"] = file_sha256(root / entry["file"])
    (root / "manifest.json").write_text(json.dumps(manifest))
    return ["check", str(root)]


def c_nan_depth(tmp: Path) -> list[str]:
    return _bad_shard(tmp, float("nan"))


def c_inf_depth(tmp: Path) -> list[str]:
    return _bad_shard(tmp, float("inf"))


def c_negative_depth(tmp: Path) -> list[str]:
    return _bad_shard(tmp, -0.2)


def c_truncated_shard(tmp: Path) -> list[str]:
    root = corpus(tmp / "corpus")
    shard = root / "shards" / "0_0.npz"
    shard.write_bytes(shard.read_bytes()[:200])
    return ["check", str(root)]


def c_unreadable_mesh(tmp: Path) -> list[str]:
    root = ycb_layout(tmp / "ycb")
    (root / "obj_models/004_sugar_box/nontextured.stl").write_bytes(b"solid x\n garbage \x00\x01")
    return ycb_recipe(tmp, root)


def c_frames_vs_poses(tmp: Path) -> list[str]:
    root = ycb_layout(tmp / "ycb")
    (root / "real/004_sugar_box/dataset_0/frames/frame_0000003.jpg").unlink()
    return ["check", str(root)]


def c_nan_poses(tmp: Path) -> list[str]:
    root = ycb_layout(tmp / "ycb")
    synced = root / "real/004_sugar_box/dataset_0/synced_data.npy"
    data = np.load(synced, allow_pickle=True).item()
    data["poses"]["DIGIT"][1, 2] = np.nan
    np.save(synced, data)
    return ["check", str(root)]


def c_other_translator_ckpt(tmp: Path) -> list[str]:
    return fit_args(tmp, cgan_from(translator_checkpoint(tmp / "sim.pt", "sim")))


def c_future_ckpt(tmp: Path) -> list[str]:
    return ["check", str(translator_checkpoint(tmp / "future.pt", "sim", format=99))]


def c_corrupt_ckpt(tmp: Path) -> list[str]:
    (tmp / "model.pt").write_bytes(os.urandom(512))
    return ["check", str(tmp / "model.pt")]


def c_truncated_ckpt(tmp: Path) -> list[str]:
    path = translator_checkpoint(tmp / "cgan.pt", "cgan")
    path.write_bytes(path.read_bytes()[:2000])
    return fit_args(tmp, cgan_from(path))


def c_mismatched_weights(tmp: Path) -> list[str]:
    path = translator_checkpoint(tmp / "cgan.pt", "cgan")
    payload = torch.load(path, weights_only=True)
    payload["config"]["generator_channels"] = 8  # the weights are of a 4-channel generator
    torch.save(payload, path)
    return ["check", str(path)]


def c_plugin_import(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + "- {name: tr, kind: translate, inputs: {data: braille}, "
    return fit_args(tmp, stages + "config: {translator: broken}}\n")


def c_plugin_not_translator(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + "- {name: tr, kind: translate, inputs: {data: braille}, "
    return fit_args(tmp, stages + "config: {translator: notone}}\n")


def c_plugin_list(tmp: Path) -> list[str]:
    return ["list", "translators"]


def c_profile_yaml(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_text("effects: [unclosed\n")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


def c_profile_effect(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_text("effects: {no_such_effect: {}}\n")
    return ["data", "ycb-slide", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "d")]


def c_profile_value(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_text("effects: {pose_error: {offset_x_mm: lots}}\n")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


def c_profile_binary(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_bytes(b"\xff\xfe\x00garbage\x89")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


def c_recipe_key(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("n_test: 4", "n_tset: 4"))


def c_recipe_missing_stage(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + "- {name: tr, kind: translate, inputs: {data: brialle}, "
    return fit_args(tmp, stages + "config: {translator: sim}}\n")


def c_recipe_binary(tmp: Path) -> list[str]:
    (tmp / "r.yaml").write_bytes(os.urandom(64))
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_missing_source(tmp: Path) -> list[str]:
    return fit_args(tmp, "- {name: corpus, kind: ycb_slide_data, config: {source: no/such/dir}}\n")


def c_recipe_profile_key(tmp: Path) -> list[str]:
    (tmp / "unit.yaml").write_text("effects: {}\ncolour: blue\n")
    stages = BRAILLE_STAGE.replace("n_classifier_test: 4", f"real_sensor: {tmp}/unit.yaml")
    return fit_args(tmp, stages)


def c_ground_background(tmp: Path) -> list[str]:
    (tmp / "real").mkdir()
    Image.fromarray(frame(0, (240, 320))).save(tmp / "real/digit_background_240x320.jpg")
    f = tmp / "real/digit_background_240x320.jpg"
    f.write_bytes(f.read_bytes()[:500])
    return ["ground", "--real-dir", str(tmp / "real")]


def c_ground_polycalib(tmp: Path) -> list[str]:
    (tmp / "real").mkdir()
    np.savez(tmp / "real/digit_polycalib.npz", grad_r=np.zeros((125, 125, 6)))
    return ["ground", "--real-dir", str(tmp / "real")]


CASES: list[Case] = [
    Case("corrupt PNG (random bytes)", c_corrupt_png, "a_0.png"),
    Case("truncated PNG", c_truncated_png, "b_1.png"),
    Case("truncated JPEG frame (YCB-Slide)", c_truncated_jpeg, "frame_0000002.jpg", slow=True),
    Case("wrong image size", c_wrong_size, "b_0.png"),
    Case("paired layout: wrong channel count (RGBA frame)", c_rgba, "c1.png"),
    Case("paired layout: grey frame where RGB expected", c_grey_frame, "c1.png"),
    Case("truncated depth mask", c_truncated_mask, "b_0.png"),
    Case("fine-tuning frame off its background's size", c_frame_off_background, "a_0.png"),
    Case("empty folder", c_empty_folder, "real_fine_tuning"),
    Case("unpaired file", c_unpaired, "b_extra.png"),
    Case("unknown label folder", c_unknown_label, "zz"),
    Case("corrupt split file", c_bad_split, "files_train_test.npy"),
    Case("paired layout: wrong image size", c_paired_wrong_size, "c1.png"),
    Case("paired layout: unpaired file", c_paired_unpaired, "c0.png"),
    Case("NaN depth in a corpus shard", c_nan_depth, "0_1.npz"),
    Case("inf depth in a corpus shard", c_inf_depth, "0_1.npz"),
    Case("negative depth in a corpus shard", c_negative_depth, "0_1.npz"),
    Case("truncated corpus shard", c_truncated_shard, "0_0.npz"),
    Case("unreadable mesh", c_unreadable_mesh, "nontextured.stl", slow=True),
    Case("frames and poses disagree", c_frames_vs_poses, "frames", slow=True),
    Case("NaN poses", c_nan_poses, "synced_data.npy", slow=True),
    Case("checkpoint of another translator", c_other_translator_ckpt, "sim.pt"),
    Case("checkpoint of a future format", c_future_ckpt, "future.pt"),
    Case("corrupt checkpoint (random bytes)", c_corrupt_ckpt, "model.pt"),
    Case("truncated checkpoint", c_truncated_ckpt, "cgan.pt"),
    Case("checkpoint weights do not fit config", c_mismatched_weights, "cgan.pt"),
    Case("plugin that fails to import", c_plugin_import, "broken", env=plugin_env),
    Case("plugin that is not a Translator", c_plugin_not_translator, "notone", env=plugin_env),
    Case("broken plugins: `list` still works", c_plugin_list, "", 0, env=plugin_env),
    Case("profile: invalid YAML", c_profile_yaml, "p.yaml"),
    Case("profile: unknown effect", c_profile_effect, "no_such_effect"),
    Case("profile: parameter of the wrong type", c_profile_value, "offset_x_mm"),
    Case("profile: binary file", c_profile_binary, "p.yaml"),
    Case("recipe: unknown config key", c_recipe_key, "n_tset"),
    Case("recipe: input from a missing stage", c_recipe_missing_stage, "brialle"),
    Case("recipe: binary garbage", c_recipe_binary, "r.yaml"),
    Case("recipe: data folder missing", c_missing_source, "no/such/dir"),
    Case("recipe: profile with an unknown key", c_recipe_profile_key, "colour"),
    Case("ground: truncated reference frame", c_ground_background, "digit_background"),
    Case("ground: calibration table lacks arrays", c_ground_polycalib, "digit_polycalib.npz"),
]

# issue 23's classes: absurd sizes, nonsense, outputs, values, duplicates, environment
CASES += [
    Case(kind, build, names, group=group, **extra)  # type: ignore[arg-type]
    for group, kind, build, names, extra in GUARD_CASES
]
