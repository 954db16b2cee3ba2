"""Tiny datasets in the layouts tactile_bench reads, for scripts/bad_input_cases.py to break.

Nothing is downloaded: each builder writes a few frames in the exact folder layout of the
original release (Tactile-Diffusion braille, YCB-Slide real), of the diagnosis's paired layout
or of a pair-set corpus, plus helpers for recipes and translator checkpoints.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import torch
from PIL import Image

FRAME_HW = (320, 240)  # a DIGIT frame, as PIL sizes go (width, height)


# ----------------------------------------------------------------------------- fixtures
def png(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)
    return path


def frame(seed: int = 0, size: tuple[int, int] = FRAME_HW) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)


def braille_layout(root: Path, letters: tuple[str, ...] = ("a", "b"), per_letter: int = 2) -> Path:
    """A tiny Tactile-Diffusion braille release (``real_fine_tuning``, ``real``, ``bgs``)."""
    split = {}
    for li, letter in enumerate(letters):
        names = [f"{letter}_{i}.png" for i in range(per_letter)]
        for i, name in enumerate(names):
            img = frame(10 * li + i)
            png(root / "real_fine_tuning/color" / letter / name, img)
            png(root / "real/color" / letter / name, img)
            mask = np.full((FRAME_HW[1], FRAME_HW[0]), 20, np.uint8)
            png(root / "real_fine_tuning/mask" / letter / name, mask)
        split[letter] = {"train": names[:-1], "test": names[-1:]}
    np.save(root / "real_fine_tuning/files_train_test.npy", split)
    png(root / "bgs/bg_10044.png", np.full((FRAME_HW[1], FRAME_HW[0], 3), 128, np.uint8))
    return root


def ycb_layout(root: Path, obj: str = "004_sugar_box", n: int = 4) -> Path:
    """A tiny YCB-Slide real release: a box mesh, one log sliding flat on its top face."""
    import trimesh
    from scipy.spatial.transform import Rotation

    (root / "obj_models" / obj).mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.08, 0.06, 0.04)).export(
        root / "obj_models" / obj / "nontextured.stl"
    )
    real = root / "real" / obj
    (real / "dataset_0" / "frames").mkdir(parents=True, exist_ok=True)
    np.save(real / "alignment.npy", np.eye(4))
    gel = np.tile(np.eye(4), (n, 1, 1))
    gel[:, 0, 3] = np.linspace(-0.01, 0.01, n)
    gel[:, 2, 3] = 0.02 + 0.022  # camera 22 mm behind the gel on the top face
    quat = Rotation.from_matrix(gel[:, :3, :3]).as_quat()
    digit = np.concatenate([gel[:, :3, 3], quat], 1)
    box = np.tile([0, 0, 0, 0, 0, 0, 1.0], (n, 1))
    np.save(real / "dataset_0" / "synced_data.npy", {"poses": {"DIGIT": digit, obj: box}})
    for i in range(n):
        Image.fromarray(frame(i)).save(real / "dataset_0" / "frames" / f"frame_{i:07d}.jpg")
    return root


def paired_layout(root: Path, n: int = 2) -> Path:
    """The diagnosis's paired layout: depth (16-bit, micrometres), sim, real, background."""
    for i in range(n):
        png(root / "depth" / f"c{i}.png", np.full((32, 32), 300, np.uint16))
        png(root / "sim" / f"c{i}.png", frame(i, (32, 32)))
        png(root / "real" / f"c{i}.png", frame(i + 5, (32, 32)))
    png(root / "background.png", frame(9, (32, 32)))
    return root


def file_sha256(path: Path) -> str:
    from tactile_bench.io import file_sha256 as sha

    return sha(path)


def corpus(root: Path) -> Path:
    """A two-shard pair-set corpus in the format the pipeline writes."""
    from tactile_bench.data.corpus import CorpusPairs
    from tactile_bench.data.ycb_slide import write_corpus

    n = 4
    pairs = CorpusPairs(
        depth=torch.full((n, 1, 16, 16), 0.5),
        real=torch.full((n, 3, 16, 16), 100, dtype=torch.uint8),
        real_background=torch.full((1, 3, 16, 16), 90, dtype=torch.uint8),
        real_bg_index=torch.zeros(n, dtype=torch.int64),
        meta={"object": np.zeros(n, np.int64), "trajectory": np.array([0, 0, 1, 1])},
    )
    write_corpus(pairs, root)
    return root


def translator_checkpoint(path: Path, name: str = "sim", **changes: object) -> Path:
    from tactile_bench.translators import create_translator

    config = {"generator_channels": 4, "discriminator_channels": 4} if name == "cgan" else {}
    translator = create_translator(name, config)
    translator.save(path)
    if changes:
        payload = torch.load(path, weights_only=True)
        payload.update(changes)
        torch.save(payload, path)
    return path


def write_recipe(path: Path, stages: str, extra: str = "") -> Path:
    path.write_text(f"name: bad\n{extra}stages:\n" + textwrap.indent(textwrap.dedent(stages), "  "))
    return path


def fit_args(tmp: Path, stages: str, extra: str = "") -> list[str]:
    recipe = write_recipe(tmp / "recipe.yaml", stages, extra)
    return ["fit", str(recipe), "--run-dir", str(tmp / "run"), "--no-progress"]


BRAILLE_STAGE = """\
- name: braille
  kind: braille_data
  config: {chars: AB, n_finetune: 4, n_test: 4, n_classifier: 4, n_classifier_test: 4}
"""


def cgan_from(checkpoint: Path) -> str:
    return BRAILLE_STAGE + textwrap.dedent(
        f"""\
        - name: fit
          kind: fit_translator
          inputs: {{braille: braille}}
          config:
            translator: cgan
            init_checkpoint: {checkpoint}
            translator_config: {{generator_channels: 4, discriminator_channels: 4}}
        """
    )


def ycb_recipe(tmp: Path, root: Path) -> list[str]:
    return fit_args(tmp, f"- {{name: corpus, kind: ycb_slide_data, config: {{source: {root}}}}}\n")


def plugin_env(tmp: Path) -> dict[str, str]:
    """A fake installed distribution whose entry points are broken, on PYTHONPATH."""
    dist = tmp / "site" / "badplugins-0.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: badplugins\nVersion: 0.0\n")
    (dist / "entry_points.txt").write_text(
        "[tactile_bench.translators]\nbroken = no_such_module_xyz:Thing\nnotone = json:dumps\n"
    )
    return {"PYTHONPATH": str(tmp / "site")}
