"""Kinds of bad input of issue 23, by class: absurd sizes, nonsense that used to exit 0,
unusable outputs, bad values, duplicates and impossible physics, the environment.

Each class is built from many kinds (not only the examples the issue listed); every case is
answered before any work: exit 2 and one ``error:`` line naming the argument, key or file.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import textwrap
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
from bad_input_fixtures import (
    BRAILLE_STAGE,
    braille_layout,
    fit_args,
    frame,
    paired_layout,
    png,
    write_recipe,
)
from PIL import Image

SIZES = "absurd sizes"
NONSENSE = "nonsense that exited 0"
OUTPUT = "unusable output"
VALUES = "bad values"
DUPES = "duplicates, physics, words"
ENV = "environment"


def args(*argv: str) -> Callable[[Path], list[str]]:
    """A case that is only a command line (``{tmp}`` is the case's folder)."""
    return lambda tmp: [a.format(tmp=tmp) for a in argv]


def png_header_only(path: Path, width: int, height: int) -> Path:
    """A PNG whose header claims ``width x height`` RGB with a tiny (incomplete) body: what
    a decompression bomb looks like to a reader that trusts the header."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    body = zlib.compress(b"\x00" * 4096)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b"")
    )
    return path


def diagnose(tmp: Path, root: Path) -> list[str]:
    return ["diagnose", str(root), "--out", str(tmp / "out"), "--no-progress", "--no-downstream"]


# ----------------------------------------------------------------------------- sizes
def c_paired_bomb(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png_header_only(root / "real" / "c1.png", 30000, 30000)
    return diagnose(tmp, root)


def c_paired_large(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png_header_only(root / "sim" / "c0.png", 6000, 5000)  # under Pillow's own bomb limit
    return diagnose(tmp, root)


def c_td_bomb(tmp: Path) -> list[str]:
    root = braille_layout(tmp / "td")
    png_header_only(root / "real_fine_tuning/color/a/a_0.png", 6000, 5000)
    return ["check", str(root)]


def c_ground_bomb(tmp: Path) -> list[str]:
    png_header_only(tmp / "real" / "digit_background_240x320.jpg", 30000, 30000)
    return ["ground", "--real-dir", str(tmp / "real")]


def c_paired_depth_bomb(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png_header_only(root / "depth" / "c0.png", 20000, 20000)
    return diagnose(tmp, root)


BOMB = "".join(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" for i in range(1, 10))


def c_recipe_bomb(tmp: Path) -> list[str]:
    (tmp / "r.yaml").write_text("name: laughs\nl0: &l0 [lol, lol]\n" + BOMB + "stages: []\n")
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_recipe_bomb_in_config(tmp: Path) -> list[str]:
    laughs = textwrap.indent("l0: &l0 [lol, lol]\n" + BOMB, "      ")
    text = (
        "name: laughs\nstages:\n  - name: braille\n    kind: braille_data\n    config:\n"
        f"      chars: AB\n      notes:\n{textwrap.indent(laughs, '  ')}"
    )
    (tmp / "r.yaml").write_text(text)
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_profile_bomb(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_text("l0: &l0 [lol, lol]\n" + BOMB + "effects: {}\n")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


def c_recipe_nesting(tmp: Path) -> list[str]:
    (tmp / "r.yaml").write_text("name: deep\nstages: " + "[" * 20000 + "]" * 20000 + "\n")
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_recipe_huge_file(tmp: Path) -> list[str]:
    (tmp / "r.yaml").write_text("name: big\n" + "# padding\n" * 300_000)
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_recipe_recursive(tmp: Path) -> list[str]:
    (tmp / "r.yaml").write_text("name: loop\nstages: &s [*s]\n")
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_recipe_big_corpus(tmp: Path) -> list[str]:
    return fit_args(
        tmp, "- {name: corpus, kind: ycb_slide_data, config: {n_pairs: 9000000, image_size: 256}}\n"
    )


def c_recipe_count(tmp: Path) -> list[str]:
    return fit_args(
        tmp, BRAILLE_STAGE.replace("n_classifier_test: 4", "n_classifier_test: 10000000000")
    )


def c_recipe_braille_memory(tmp: Path) -> list[str]:
    return fit_args(
        tmp,
        BRAILLE_STAGE.replace(
            "n_classifier_test: 4", "n_classifier_test: 9000000, image_size: 256"
        ),
    )


# ----------------------------------------------------------------------------- nonsense
def c_n_classifier(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("n_classifier: 4", "n_classifier: 1000000"))


def c_finetune_grid(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("n_finetune: 4", "n_finetune: 400"))


def c_dup_chars(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("chars: AB", "chars: AAB"))


def c_dup_seeds(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + (
        "- {name: c, kind: classify, inputs: {data: braille}, "
        "config: {row: sim, train_images: sim, seeds: [0, 1, 0]}}\n"
    )
    return fit_args(tmp, stages)


def c_dup_objects(tmp: Path) -> list[str]:
    return fit_args(
        tmp, "- {name: corpus, kind: ycb_slide_data, config: {objects: [025_mug, 025_mug]}}\n"
    )


def c_ground_empty(tmp: Path) -> list[str]:
    (tmp / "empty").mkdir()
    return ["ground", "--real-dir", str(tmp / "empty")]


def c_tiny_gap(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired", n=6)
    for i in range(6):
        sim = np.asarray(Image.open(root / "sim" / f"c{i}.png")).copy()
        sim[5, 5, 0] = sim[5, 5, 0] ^ 1  # one level in one pixel
        png(root / "real" / f"c{i}.png", sim)
    return diagnose(tmp, root)


def c_no_gap(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired", n=6)
    for i in range(6):
        (root / "real" / f"c{i}.png").write_bytes((root / "sim" / f"c{i}.png").read_bytes())
    return diagnose(tmp, root)


# ----------------------------------------------------------------------------- outputs
def _file(tmp: Path) -> Path:
    (tmp / "f.txt").write_text("a file")
    return tmp / "f.txt"


def c_out_is_file(tmp: Path) -> list[str]:
    return diagnose(tmp, paired_layout(tmp / "paired"))[:3] + [str(_file(tmp))]


def c_out_under_file(tmp: Path) -> list[str]:
    return diagnose(tmp, paired_layout(tmp / "paired"))[:3] + [str(_file(tmp) / "sub")]


def c_run_dir_file(tmp: Path) -> list[str]:
    out = fit_args(tmp, BRAILLE_STAGE)
    return out[:3] + [str(_file(tmp))] + out[4:]


def c_run_dir_under_file(tmp: Path) -> list[str]:
    out = fit_args(tmp, BRAILLE_STAGE)
    return out[:3] + [str(_file(tmp) / "run")] + out[4:]


def c_recipe_run_dir_file(tmp: Path) -> list[str]:
    _file(tmp)
    write_recipe(tmp / "recipe.yaml", BRAILLE_STAGE, extra=f"run_dir: {tmp}/f.txt\n")
    return ["fit", str(tmp / "recipe.yaml"), "--no-progress"]


def c_export_out_file(tmp: Path) -> list[str]:
    return ["export-pairs", "--generate", "4", "--out", str(_file(tmp))]


def c_data_out_under_file(tmp: Path) -> list[str]:
    return ["data", "ycb-slide", "--pairs", "20", "--out", str(_file(tmp) / "corpus")]


def c_render_out_folder(tmp: Path) -> list[str]:
    (tmp / "sheet.png").mkdir()
    return ["render", "--out", str(tmp / "sheet.png")]


def c_render_under_file(tmp: Path) -> list[str]:
    return ["render", "--out", str(_file(tmp) / "sheet.png")]


def c_validate_out_file(tmp: Path) -> list[str]:
    return ["validate-diagnosis", "--quick", "--out", str(_file(tmp))]


def c_bench_out_file(tmp: Path) -> list[str]:
    return ["bench", "--quick", "--out", str(_file(tmp))]


def c_rt_out_file(tmp: Path) -> list[str]:
    return ["real-translators", "gelsight", "--out", str(_file(tmp))]


def c_dangling_out(tmp: Path) -> list[str]:
    (tmp / "link").symlink_to(tmp / "nowhere" / "deeper")
    return diagnose(tmp, paired_layout(tmp / "paired"))[:3] + [str(tmp / "link" / "out")]


def c_out_locked(tmp: Path) -> list[str]:
    """Another process holds the output (it lets go after 20 s)."""
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time\nfrom tactile_bench.guard.outputs import OutputLock\n"
            f"with OutputLock({str(tmp / 'out')!r}, '--out'):\n"
            "    print('held', flush=True); time.sleep(20)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    return diagnose(tmp, paired_layout(tmp / "paired"))


# ----------------------------------------------------------------------------- values
def c_recipe_seed(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE, extra="seed: -3\n")


def c_recipe_seed_big(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE, extra="seed: 18446744073709551616\n")


def c_trainer_key(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + (
        "- {name: c, kind: classify, inputs: {data: braille}, "
        "config: {row: sim, train_images: sim}}\n"
    )
    return fit_args(tmp, stages, extra="trainer: {max_epoch: 2}\n")


def c_trainer_negative(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE, extra="trainer: {max_epochs: -1}\n")


def trainer(settings: str) -> Callable[[Path], list[str]]:
    """A recipe whose ``trainer:`` Lightning would refuse only at the first fit."""
    return lambda tmp: fit_args(tmp, BRAILLE_STAGE, extra=f"trainer: {settings}\n")


def c_ablation_seed(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + (
        "- {name: c, kind: classify, inputs: {data: braille}, config: {row: sim, "
        "train_images: sim}}\n- {name: ab, kind: effect_ablation, inputs: {data: braille, "
        "classifier: c}, config: {seed: -7}}\n"
    )
    return fit_args(tmp, stages)


def c_set_broken_yaml(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE) + ["--set", "braille.n_test=[1,"]


def c_set_seed(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE) + ["--set", "seed=-1"]


def c_set_bomb(tmp: Path) -> list[str]:
    levels = ["&l0 [lol, lol]"] + [f"&l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 10)]
    return fit_args(tmp, BRAILLE_STAGE) + ["--set", f"braille.notes=[{', '.join(levels)}]"]


# ----------------------------------------------------------------------------- duplicates
def c_label_aliases(tmp: Path) -> list[str]:
    root = tmp / "paired"
    for label in ("number_sign", "%23"):
        png(root / "depth" / label / "c0.png", np.full((32, 32), 300, np.uint16))
        png(root / "sim" / label / "c0.png", frame(1, (32, 32)))
        png(root / "real" / label / "c0.png", frame(2, (32, 32)))
    png(root / "background.png", frame(9, (32, 32)))
    return diagnose(tmp, root)


def c_case_twins(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    for part in ("depth", "sim", "real"):
        (root / part / "C0.PNG").write_bytes((root / part / "c0.png").read_bytes())
    return diagnose(tmp, root)


def c_depth_65mm(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png(root / "depth" / "c1.png", np.full((32, 32), 65000, np.uint16))
    return diagnose(tmp, root)


def c_check_depth_65mm(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    png(root / "depth" / "c0.png", np.full((32, 32), 65000, np.uint16))
    return ["check", "--layout", "paired", str(root)]


def c_tiny_images(tmp: Path) -> list[str]:
    root = tmp / "paired"
    png(root / "depth" / "c0.png", np.full((1, 1), 300, np.uint16))
    png(root / "sim" / "c0.png", frame(1, (1, 1)))
    png(root / "real" / "c0.png", frame(2, (1, 1)))
    png(root / "background.png", frame(9, (1, 1)))
    return diagnose(tmp, root)


def c_check_paired_file(tmp: Path) -> list[str]:
    return ["check", "--layout", "paired", str(_file(tmp))]


def c_diagnose_file(tmp: Path) -> list[str]:
    return diagnose(tmp, _file(tmp))


def c_recipe_dup_key(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE, extra="seed: 1\nseed: 2\n")


def c_recipe_dup_config_key(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("n_test: 4", "n_test: 4, n_test: 8"))


def c_profile_dup_key(tmp: Path) -> list[str]:
    (tmp / "p.yaml").write_text("effects: {}\neffects: {camera_noise: {}}\n")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


# ----------------------------------------------------------------------------- environment
def c_fifo_recipe(tmp: Path) -> list[str]:
    os.mkfifo(tmp / "r.yaml")
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_fifo_profile(tmp: Path) -> list[str]:
    os.mkfifo(tmp / "p.yaml")
    return ["render", "--profile", str(tmp / "p.yaml"), "--out", str(tmp / "x.png")]


def c_recipe_folder(tmp: Path) -> list[str]:
    (tmp / "r.yaml").mkdir()
    return ["fit", str(tmp / "r.yaml"), "--run-dir", str(tmp / "run")]


def c_recipe_device(tmp: Path) -> list[str]:
    return ["fit", "/dev/zero", "--run-dir", str(tmp / "run")]


def wandb_online_env(tmp: Path) -> dict[str, str]:
    return {
        "TACTILE_BENCH_NO_WANDB": "",
        "WANDB_MODE": "online",
        "WANDB_API_KEY": "",
        "HOME": str(tmp),
        "NETRC": str(tmp / "no.netrc"),
    }


def quitter_env(tmp: Path) -> dict[str, str]:
    """An installed plugin whose module calls ``sys.exit(3)`` on import."""
    site = tmp / "site"
    dist = site / "quitter-0.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: quitter\nVersion: 0.0\n")
    (dist / "entry_points.txt").write_text("[tactile_bench.translators]\nquitter = quitter:T\n")
    (site / "quitter.py").write_text("import sys\nsys.exit(3)\n")
    return {"PYTHONPATH": str(site)}


def c_quitter_fit(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + "- {name: tr, kind: translate, inputs: {data: braille}, "
    return fit_args(tmp, stages + "config: {translator: quitter}}\n")


def c_long_out(tmp: Path) -> list[str]:
    return diagnose(tmp, paired_layout(tmp / "paired"))[:3] + [str(tmp / ("x" * 300))]


def c_long_input(tmp: Path) -> list[str]:
    return diagnose(tmp, tmp / ("p" * 300))


def c_non_utf8_name(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    bad = os.fsencode(root / "real") + b"/\xff\xfe.txt"
    with open(bad, "wb") as handle:
        handle.write(b"x")
    return diagnose(tmp, root)


def c_nfd_twins(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    for part in ("depth", "sim", "real"):
        data = (root / part / "c0.png").read_bytes()
        (root / part / "caf\u00e9.png").write_bytes(data)  # NFC
        (root / part / "cafe\u0301.png").write_bytes(data)  # NFD: the same name to a reader
    return diagnose(tmp, root)


def c_no_contact(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired", n=6)
    for i in range(6):
        png(root / "depth" / f"c{i}.png", np.zeros((32, 32), np.uint16))
    return diagnose(tmp, root)


def c_recipe_nan(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + (
        "- {name: c, kind: classify, inputs: {data: braille}, "
        "config: {row: sim, train_images: sim, classifier: {lr: .nan}}}\n"
    )
    return fit_args(tmp, stages)


def c_recipe_long_name(tmp: Path) -> list[str]:
    return fit_args(tmp, BRAILLE_STAGE.replace("name: braille", "name: " + "b" * 300))


def c_recipe_batch(tmp: Path) -> list[str]:
    stages = BRAILLE_STAGE + (
        "- {name: t, kind: translate, inputs: {data: braille}, "
        "config: {translator: sim, batch_size: 9000000}}\n"
    )
    return fit_args(tmp, stages)


def c_out_is_input(tmp: Path) -> list[str]:
    root = paired_layout(tmp / "paired")
    return diagnose(tmp, root)[:3] + [str(root)]


def c_export_over_source(tmp: Path) -> list[str]:
    return ["export-pairs", str(tmp / "run" / "braille"), "--out", str(tmp), "--overwrite"]


def c_fifo_checkpoint(tmp: Path) -> list[str]:
    os.mkfifo(tmp / "cgan.pt")
    from bad_input_fixtures import cgan_from

    return fit_args(tmp, cgan_from(tmp / "cgan.pt"))


def c_fifo_pairs_arg(tmp: Path) -> list[str]:
    os.mkfifo(tmp / "pairs")
    return diagnose(tmp, tmp / "pairs")


def c_fifo_npz(tmp: Path) -> list[str]:
    (tmp / "real").mkdir()
    os.mkfifo(tmp / "real" / "digit_polycalib.npz")
    return ["ground", "--real-dir", str(tmp / "real")]


A = args
GUARD_CASES: list[tuple[str, str, Callable[[Path], list[str]], str, dict]] = [
    # (class, kind, build, the error line must name, extra Case fields)
    (
        SIZES,
        "export-pairs: 2 pairs of 100000 x 100000",
        A("export-pairs", "--generate", "2", "--size", "100000", "--out", "{tmp}/o"),
        "707.8 GiB",
        {},
    ),
    (
        SIZES,
        "export-pairs: 10 million pairs of 4096 x 4096",
        A("export-pairs", "--generate", "10000000", "--size", "4096", "--out", "{tmp}/o"),
        "--generate",
        {},
    ),
    (
        SIZES,
        "data ycb-slide: a billion pairs",
        A("data", "ycb-slide", "--pairs", "1000000000", "--out", "{tmp}/d"),
        "--pairs 1000000000",
        {},
    ),
    (
        SIZES,
        "data ycb-slide: more pairs than the disk holds",
        A("data", "ycb-slide", "--pairs", "9000000", "--out", "{tmp}/d"),
        "free on the disk",
        {"env": lambda tmp: {"TACTILE_BENCH_MEMORY_LIMIT": "1000T"}},
    ),
    (
        SIZES,
        "validate-diagnosis: 5 million pairs of 4096",
        A("validate-diagnosis", "--pairs", "5000000", "--size", "4096", "--out", "{tmp}/v"),
        "--pairs",
        {},
    ),
    (
        SIZES,
        "real-translators: 9 million pretraining pairs",
        A("real-translators", "gelsight", "--pretrain-pairs", "9000000", "--out", "{tmp}/rt"),
        "--pretrain-pairs",
        {},
    ),
    (
        SIZES,
        "bench: ten billion DDPM images",
        A("bench", "--ddpm-images", "10000000000", "--out", "{tmp}/b"),
        "--ddpm-images",
        {},
    ),
    (SIZES, "paired: a 30000 x 30000 PNG of a few KB", c_paired_bomb, "c1.png", {}),
    (SIZES, "paired: a 6000 x 5000 PNG (below Pillow's bomb limit)", c_paired_large, "c0.png", {}),
    (SIZES, "paired: a 20000 x 20000 depth PNG", c_paired_depth_bomb, "c0.png", {}),
    (SIZES, "Tactile-Diffusion layout: a 6000 x 5000 frame", c_td_bomb, "a_0.png", {}),
    (SIZES, "ground: a 30000 x 30000 reference frame", c_ground_bomb, "digit_background", {}),
    (SIZES, "recipe: nested aliases (billion laughs)", c_recipe_bomb, "r.yaml", {}),
    (SIZES, "recipe: billion laughs inside a stage config", c_recipe_bomb_in_config, "r.yaml", {}),
    (SIZES, "profile: nested aliases", c_profile_bomb, "p.yaml", {}),
    (SIZES, "recipe: 20000 nested brackets", c_recipe_nesting, "r.yaml", {}),
    (SIZES, "recipe: a 3 MB file", c_recipe_huge_file, "r.yaml", {}),
    (SIZES, "recipe: a translate batch of 9 million", c_recipe_batch, "batch_size", {}),
    (SIZES, "read: a word of 100000 characters", A("read", "--word", "A" * 100000), "--word", {}),
    (
        SIZES,
        "read: a step of a nanometre",
        A("read", "--word", "DIGIT", "--step-mm", "0.000001"),
        "--step-mm",
        {},
    ),
    (
        SIZES,
        "export-pairs --real-presses at 4096 px",
        A("export-pairs", "--real-presses", "gelsight", "--size", "4096", "--out", "{tmp}/o"),
        "--size",
        {"env": lambda tmp: {"TACTILE_BENCH_MEMORY_LIMIT": "8G"}},
    ),
    (SIZES, "recipe: a recursive alias", c_recipe_recursive, "r.yaml", {}),
    (SIZES, "recipe: 9 million corpus pairs at 256 px", c_recipe_big_corpus, "n_pairs", {}),
    (
        SIZES,
        "recipe: ten billion classifier test contacts",
        c_recipe_count,
        "n_classifier_test",
        {},
    ),
    (SIZES, "recipe: braille sets beyond memory", c_recipe_braille_memory, "of memory", {}),
    (SIZES, "--set: an alias bomb as a value", c_set_bomb, "--set", {}),
    (NONSENSE, "recipe: n_classifier above the grid", c_n_classifier, "n_classifier", {}),
    (NONSENSE, "recipe: n_finetune + n_test above the grid", c_finetune_grid, "n_finetune", {}),
    (NONSENSE, "recipe: a character twice (chars AAB)", c_dup_chars, "chars", {}),
    (NONSENSE, "recipe: a seed twice in seeds", c_dup_seeds, "seeds", {}),
    (NONSENSE, "recipe: an object twice", c_dup_objects, "objects", {}),
    (
        NONSENSE,
        "validate-diagnosis --pairs 0",
        A("validate-diagnosis", "--pairs", "0", "--out", "{tmp}/v"),
        "--pairs",
        {},
    ),
    (
        NONSENSE,
        "validate-diagnosis --pairs 3",
        A("validate-diagnosis", "--pairs", "3", "--out", "{tmp}/v"),
        "--pairs",
        {},
    ),
    (
        NONSENSE,
        "--threads 0 (not 'the default')",
        A("--threads", "0", "list", "recipes"),
        "--threads",
        {},
    ),
    (
        NONSENSE,
        "export-pairs --generate 0",
        A("export-pairs", "--generate", "0", "--out", "{tmp}/o"),
        "--generate",
        {},
    ),
    (
        NONSENSE,
        "export-pairs --chars AAB",
        A("export-pairs", "--generate", "4", "--chars", "AAB", "--out", "{tmp}/o"),
        "--chars",
        {},
    ),
    (
        NONSENSE,
        "render --chars A A",
        A("render", "--chars", "A", "A", "--out", "{tmp}/x.png"),
        "--chars",
        {},
    ),
    (
        NONSENSE,
        "diagnose --candidates twice the same",
        A("diagnose", "{tmp}", "--out", "{tmp}/o", "--candidates", "jpeg", "jpeg"),
        "--candidates",
        {},
    ),
    (
        NONSENSE,
        "data ycb-slide --objects twice the same",
        A("data", "ycb-slide", "--objects", "025_mug", "025_mug", "--out", "{tmp}/d"),
        "--objects",
        {},
    ),
    (NONSENSE, "bench --only with nothing", A("bench", "--only", "--out", "{tmp}/b"), "--only", {}),
    (
        NONSENSE,
        "diagnose: real = sim but one level in one pixel",
        c_tiny_gap,
        "no sim-to-real gap",
        {},
    ),
    (NONSENSE, "ground --real-dir on an empty folder", c_ground_empty, "nothing to measure", {}),
    (NONSENSE, "diagnose: real images equal the sim images", c_no_gap, "no sim-to-real gap", {}),
    (OUTPUT, "diagnose --out is a file", c_out_is_file, "f.txt", {}),
    (OUTPUT, "diagnose --out lies under a file", c_out_under_file, "f.txt", {}),
    (OUTPUT, "fit --run-dir is a file", c_run_dir_file, "f.txt", {}),
    (OUTPUT, "fit --run-dir lies under a file", c_run_dir_under_file, "f.txt", {}),
    (OUTPUT, "recipe run_dir is a file", c_recipe_run_dir_file, "f.txt", {}),
    (OUTPUT, "export-pairs --out is a file", c_export_out_file, "f.txt", {}),
    (OUTPUT, "data ycb-slide --out under a file", c_data_out_under_file, "f.txt", {}),
    (OUTPUT, "render --out is a folder", c_render_out_folder, "sheet.png", {}),
    (OUTPUT, "render --out under a file", c_render_under_file, "f.txt", {}),
    (
        OUTPUT,
        "render --out sheet.jpg (PNG bytes)",
        A("render", "--out", "{tmp}/sheet.jpg"),
        "sheet.jpg",
        {},
    ),
    (OUTPUT, "render --out without a suffix", A("render", "--out", "{tmp}/sheet"), "sheet", {}),
    (
        OUTPUT,
        "read --save-frames frames.jpg",
        A("read", "--save-frames", "{tmp}/frames.jpg"),
        "frames.jpg",
        {},
    ),
    (
        OUTPUT,
        "ground --figure under a file",
        lambda tmp: ["ground", "--profile", "gelsight", "--figure", str(_file(tmp) / "g.png")],
        "f.txt",
        {},
    ),
    (OUTPUT, "validate-diagnosis --out is a file", c_validate_out_file, "f.txt", {}),
    (OUTPUT, "bench --out is a file", c_bench_out_file, "f.txt", {}),
    (OUTPUT, "real-translators --out is a file", c_rt_out_file, "f.txt", {}),
    (OUTPUT, "--out through a dangling symbolic link", c_dangling_out, "dangling", {}),
    (OUTPUT, "--out held by another running process", c_out_locked, "in use by process", {}),
    (OUTPUT, "diagnose --out is the input folder", c_out_is_input, "holds the input", {}),
    (
        OUTPUT,
        "export-pairs --overwrite over its own source",
        c_export_over_source,
        "holds the input",
        {},
    ),
    (
        VALUES,
        "export-pairs --seed -1",
        A("export-pairs", "--generate", "4", "--seed", "-1", "--out", "{tmp}/o"),
        "--seed",
        {},
    ),
    (VALUES, "render --seed -1", A("render", "--seed", "-1", "--out", "{tmp}/x.png"), "--seed", {}),
    (
        VALUES,
        "data ycb-slide --seed -1",
        A("data", "ycb-slide", "--seed", "-1", "--out", "{tmp}/d"),
        "--seed",
        {},
    ),
    (
        VALUES,
        "diagnose --seed 2**32",
        A("diagnose", "{tmp}", "--out", "{tmp}/o", "--seed", "4294967296"),
        "--seed",
        {},
    ),
    (VALUES, "read --model-seed -1", A("read", "--model-seed", "-1"), "--model-seed", {}),
    (VALUES, "recipe seed: -3", c_recipe_seed, "seed", {}),
    (VALUES, "recipe seed: 2**64", c_recipe_seed_big, "seed", {}),
    (VALUES, "effect_ablation seed: -7", c_ablation_seed, "seed", {}),
    (VALUES, "--set seed=-1", c_set_seed, "seed", {}),
    (VALUES, "--threads -1", A("--threads", "-1", "list", "recipes"), "--threads", {}),
    (VALUES, "--threads abc", A("--threads", "abc", "list", "recipes"), "--threads", {}),
    (
        VALUES,
        "bench --repeats 0",
        A("bench", "--repeats", "0", "--out", "{tmp}/b"),
        "--repeats",
        {},
    ),
    (
        VALUES,
        "validate-diagnosis --size 2",
        A("validate-diagnosis", "--size", "2", "--out", "{tmp}/v"),
        "--size",
        {},
    ),
    (
        VALUES,
        "diagnose --fit-fraction 1.5",
        A("diagnose", "{tmp}", "--out", "{tmp}/o", "--fit-fraction", "1.5"),
        "--fit-fraction",
        {},
    ),
    (
        VALUES,
        "diagnose --fit-fraction nan",
        A("diagnose", "{tmp}", "--out", "{tmp}/o", "--fit-fraction", "nan"),
        "--fit-fraction",
        {},
    ),
    (VALUES, "read --press-mm 65", A("read", "--press-mm", "65"), "--press-mm", {}),
    (VALUES, "read --step-mm -1", A("read", "--step-mm", "-1"), "--step-mm", {}),
    (VALUES, "read --pitch-mm inf", A("read", "--pitch-mm", "inf"), "--pitch-mm", {}),
    (VALUES, "--set 'braille.n_test=[1,'", c_set_broken_yaml, "--set", {}),
    (
        VALUES,
        "render --chars --objects (both empty)",
        A("render", "--chars", "--objects", "--out", "{tmp}/x.png"),
        "--chars",
        {},
    ),
    (VALUES, "recipe: unknown trainer key", c_trainer_key, "max_epoch", {}),
    (VALUES, "recipe: trainer max_epochs -1", c_trainer_negative, "max_epochs", {}),
    (VALUES, "recipe: trainer precision bf17", trainer("{precision: bf17}"), "precision", {}),
    (VALUES, "recipe: trainer strategy nope", trainer("{strategy: nope}"), "strategy", {}),
    (VALUES, "recipe: trainer devices 0", trainer("{devices: 0}"), "devices", {}),
    (VALUES, "recipe: trainer accelerator tpu", trainer("{accelerator: tpu}"), "trainer", {}),
    (VALUES, "recipe: trainer callbacks 3", trainer("{callbacks: 3}"), "callbacks", {}),
    (
        VALUES,
        "recipe: trainer default_root_dir",
        trainer("{default_root_dir: 5}"),
        "default_root_dir",
        {},
    ),
    (
        VALUES,
        "real-translators --cgan-steps 0",
        A("real-translators", "gelsight", "--cgan-steps", "0", "--out", "{tmp}/rt"),
        "--cgan-steps",
        {},
    ),
    (
        VALUES,
        "export-pairs --size 8",
        A("export-pairs", "--generate", "4", "--size", "8", "--out", "{tmp}/o"),
        "--size",
        {},
    ),
    (DUPES, "paired: label folders number_sign and %23", c_label_aliases, "c0.png", {}),
    (DUPES, "paired: X.PNG beside X.png", c_case_twins, "C0.PNG", {}),
    (DUPES, "paired: one name in NFC and NFD", c_nfd_twins, "caf", {}),
    (DUPES, "paired: no contact in any pair", c_no_contact, "no pair has any contact", {}),
    (DUPES, "recipe: a NaN learning rate", c_recipe_nan, "lr", {}),
    (DUPES, "recipe: a stage name of 300 characters", c_recipe_long_name, "300 characters", {}),
    (DUPES, "paired: a depth of 65 mm", c_depth_65mm, "c1.png", {}),
    (DUPES, "check: a paired depth of 65 mm", c_check_depth_65mm, "c0.png", {}),
    (DUPES, "paired: 1 x 1 images", c_tiny_images, "c0.png", {}),
    (
        DUPES,
        "diagnose --max-pairs 0",
        A("diagnose", "{tmp}", "--out", "{tmp}/o", "--max-pairs", "0"),
        "--max-pairs",
        {},
    ),
    (DUPES, "check --layout paired FILE", c_check_paired_file, "f.txt", {}),
    (DUPES, "diagnose on a file", c_diagnose_file, "f.txt", {}),
    (DUPES, "recipe: a key written twice", c_recipe_dup_key, "seed", {}),
    (DUPES, "recipe: a config key written twice", c_recipe_dup_config_key, "n_test", {}),
    (DUPES, "profile: a key written twice", c_profile_dup_key, "effects", {}),
    (ENV, "recipe is a FIFO", c_fifo_recipe, "r.yaml", {}),
    (ENV, "recipe's init_checkpoint is a FIFO", c_fifo_checkpoint, "cgan.pt", {}),
    (ENV, "the paired folder argument is a FIFO", c_fifo_pairs_arg, "FIFO", {}),
    (ENV, "ground: the calibration table is a FIFO", c_fifo_npz, "digit_polycalib.npz", {}),
    (ENV, "--out name longer than the file system takes", c_long_out, "too long", {}),
    (ENV, "input folder name longer than the file system takes", c_long_input, "pppp", {}),
    (ENV, "a file name that is not UTF-8 in the pairs", c_non_utf8_name, "\\udcff", {}),
    (ENV, "profile is a FIFO", c_fifo_profile, "p.yaml", {}),
    (ENV, "recipe is a folder", c_recipe_folder, "r.yaml", {}),
    (ENV, "recipe is a device (/dev/zero)", c_recipe_device, "/dev/zero", {}),
    (
        ENV,
        "WANDB_MODE=online without a key",
        lambda tmp: fit_args(tmp, BRAILLE_STAGE),
        "WANDB_MODE",
        {"env": wandb_online_env},
    ),
    (ENV, "plugin calls sys.exit() on import: fit", c_quitter_fit, "quitter", {"env": quitter_env}),
    (
        ENV,
        "plugin calls sys.exit() on import: list",
        A("list", "translators"),
        "",
        {"env": quitter_env, "expect_exit": 0},
    ),
    (
        ENV,
        "TACTILE_BENCH_MEMORY_LIMIT is not a size",
        A("export-pairs", "--generate", "4", "--out", "{tmp}/o"),
        "TACTILE_BENCH_MEMORY_LIMIT",
        {"env": lambda tmp: {"TACTILE_BENCH_MEMORY_LIMIT": "lots"}},
    ),
]
