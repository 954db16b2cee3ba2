"""Random bytes and random images fed to every loader of user files: each loads or raises
TactileBenchError with a one-line message, never anything else. (Recipes: test_fuzz_recipes.)"""

from __future__ import annotations

import io
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from tactile_bench.data.corpus import load_pairs
from tactile_bench.data.images import read_image, read_mask
from tactile_bench.data.tactile_diffusion import load_braille_pairs, read_split
from tactile_bench.errors import TactileBenchError
from tactile_bench.io import load_npz
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.translators.registry import load_checkpoint
from tactile_bench.translators.sim import SimTranslator

try:
    from tactile_bench.diagnose.paired import load_paired
except ImportError:  # pragma: no cover - the diagnosis is optional here
    load_paired = None

FAST = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))

# Prefixes that get random bytes past the first check of each format.
MAGIC = [b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff\xe0", b"PK\x03\x04", b"\x93NUMPY\x01\x00"]
random_files = st.builds(lambda m, b: m + b, st.sampled_from(MAGIC), st.binary(max_size=400))


def _one_line(call: Callable[[], Any]) -> None:
    """Any exception but TactileBenchError propagates and fails the test."""
    try:
        call()
    except TactileBenchError as exc:
        assert str(exc).strip() and "\n" not in str(exc).strip()


def _file_loaders() -> dict[str, tuple[str, Callable[[Path], Any]]]:
    return {
        "read_image": (".png", read_image),
        "read_mask": (".png", read_mask),
        "load_npz": (".npz", lambda p: load_npz(p, ("depth",))),
        "translator_load": (".pt", SimTranslator.load),
        "load_checkpoint": (".pt", load_checkpoint),
        "profile": (".yaml", SurrogateDigit.from_profile),
        "split_file": (".npy", read_split),
    }


@pytest.mark.parametrize("loader", sorted(_file_loaders()))
@FAST
@given(data=random_files)
def test_random_bytes_to_file_loaders(loader: str, data: bytes) -> None:
    suffix, load = _file_loaders()[loader]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"x{suffix}"
        path.write_bytes(data)
        _one_line(lambda: load(path))


MODES = ["1", "L", "LA", "P", "RGB", "RGBA", "I;16", "CMYK", "F"]


@st.composite
def images(draw: Any) -> bytes:
    """An image file of a random size, mode and format (sometimes cut short)."""
    mode = draw(st.sampled_from(MODES))
    fmt = draw(st.sampled_from(["PNG", "JPEG", "TIFF", "BMP"]))
    w, h = draw(st.integers(1, 48)), draw(st.integers(1, 48))
    seed = draw(st.integers(0, 2**16))
    arr = np.random.default_rng(seed).integers(0, 255, (h, w, 4), dtype=np.uint8)
    try:
        im = Image.fromarray(arr[..., :3]).convert(mode)
        buffer = io.BytesIO()
        im.save(buffer, format=fmt)
    except (OSError, ValueError, KeyError):  # this format cannot hold this mode
        buffer = io.BytesIO()
        Image.fromarray(arr[..., :3]).save(buffer, format="PNG")
    data = buffer.getvalue()
    cut = draw(st.sampled_from([None, None, 0.5, 0.9]))
    return data if cut is None else data[: int(len(data) * cut)]


@FAST
@given(image=images())
def test_random_images_to_image_readers(image: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame.png"
        path.write_bytes(image)
        _one_line(lambda: read_image(path, 16))
        _one_line(lambda: read_mask(path, 16))


def _braille_layout(root: Path) -> Path:
    for letter in ("a", "b"):
        for sub, arr in (
            ("color", np.full((24, 32, 3), 100, np.uint8)),
            ("mask", np.full((24, 32), 20, np.uint8)),
        ):
            folder = root / "real_fine_tuning" / sub / letter
            folder.mkdir(parents=True)
            Image.fromarray(arr).save(folder / f"{letter}_0.png")
    (root / "bgs").mkdir()
    Image.fromarray(np.full((24, 32, 3), 128, np.uint8)).save(root / "bgs/bg_10044.png")
    return root


@FAST
@given(
    image=st.one_of(images(), random_files),
    where=st.sampled_from(["color/a/a_0.png", "mask/b/b_0.png", "color/b/extra.png"]),
)
def test_random_files_in_a_tactile_diffusion_layout(image: bytes, where: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = _braille_layout(Path(tmp))
        (root / "real_fine_tuning" / where).write_bytes(image)
        _one_line(lambda: load_braille_pairs(root, "all"))
        skipped: list[tuple[str, str]] = []
        _one_line(lambda: load_braille_pairs(root, "all", skipped=skipped))
        assert all("\n" not in why for _, why in skipped)


@pytest.mark.skipif(load_paired is None, reason="no tactile_bench.diagnose.paired")
@FAST
@given(
    image=st.one_of(images(), random_files),
    where=st.sampled_from(["depth/c0.png", "sim/c0.png", "real/c1.png", "background.png"]),
)
def test_random_files_in_a_paired_layout(image: bytes, where: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for part in ("depth", "sim", "real"):
            (root / part).mkdir()
            for i in range(2):
                arr = (
                    np.full((16, 16), 300, np.uint16)
                    if part == "depth"
                    else np.zeros((16, 16, 3), np.uint8)
                )
                Image.fromarray(arr).save(root / part / f"c{i}.png")
        Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(root / "background.png")
        (root / where).write_bytes(image)
        _one_line(lambda: load_paired(root))


@FAST
@given(manifest=random_files, shard=random_files)
def test_random_corpus_files(manifest: bytes, shard: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "shards").mkdir()
        (root / "manifest.json").write_bytes(manifest)
        (root / "shards" / "0_0.npz").write_bytes(shard)
        (root / "backgrounds.npz").write_bytes(shard)
        _one_line(lambda: load_pairs(root, "all"))
