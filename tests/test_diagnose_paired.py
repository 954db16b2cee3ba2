"""Paired layout: round trip, label folder names, the Tactile-Diffusion layout, bad input."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image

from tactile_bench.data.corpus import CorpusPairs
from tactile_bench.diagnose.paired import (
    DiagnosisPairs,
    data_hash,
    detect_layout,
    dir_to_label,
    label_to_dir,
    load_paired,
    write_paired,
)
from tactile_bench.errors import TactileBenchError
from tests.data.make_layouts import make_braille_layout


def tiny_pairs(n: int = 12, size: int = 32, seed: int = 0) -> DiagnosisPairs:
    """``n`` pairs over labels A, B, # with one round dent each; real = sim + an offset."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    depth = torch.zeros(n, 1, size, size)
    for i in range(n):
        cy, cx = torch.randint(8, size - 8, (2,), generator=g).tolist()
        r2 = ((yy - cy) ** 2 + (xx - cx) ** 2).float()
        depth[i, 0] = (0.5 - r2 / 40).clamp(min=0)
    sim = (torch.rand(n, 3, size, size, generator=g) * 200 + 20).round()
    real = (sim + 10).clamp(0, 255)
    background = torch.full((3, size, size), 120.0)
    labels = [("A", "B", "#")[i % 3] for i in range(n)]
    return DiagnosisPairs(
        depth, sim, real, background, background - 5, labels, [f"p{i:02d}" for i in range(n)]
    )


def _by_key(data: DiagnosisPairs) -> dict[tuple[str, str], int]:
    return {
        (lab, name): i for i, (lab, name) in enumerate(zip(data.labels, data.names, strict=True))
    }


def test_round_trip(tmp_path: Path) -> None:
    data = tiny_pairs()
    root = write_paired(tmp_path / "pairs", data)
    assert (root / "depth" / "number_sign").is_dir()  # '#' gets a safe folder name
    assert Image.open(root / "depth" / "A" / "p00.png").mode == "I;16"
    back = load_paired(root)
    assert detect_layout(root)[0] == "paired"
    assert len(back) == len(data) and back.size == 32
    ref, got = _by_key(data), _by_key(back)
    assert set(ref) == set(got)
    order = [ref[k] for k in got]
    assert torch.equal(back.sim, data.sim[order])
    assert torch.equal(back.real, data.real[order])
    assert (back.depth - data.depth[order]).abs().max() <= 0.0005 + 1e-6  # whole micrometres
    assert torch.equal(back.background, data.background)
    assert back.sim_background is not None and torch.equal(back.sim_background, data.sim_background)
    assert data_hash(back) == data_hash(data.subset(order))


def test_unlabelled_and_no_sim_background(tmp_path: Path) -> None:
    data = tiny_pairs(n=5)
    data = DiagnosisPairs(
        data.depth, data.sim, data.real, data.background, None, [""] * 5, data.names
    )
    root = write_paired(tmp_path / "u", data)
    assert (root / "depth" / "p00.png").is_file() and not (root / "sim_background.png").exists()
    back = load_paired(root)
    assert back.labels == [""] * 5 and back.sim_background is None


@pytest.mark.parametrize("label", ["#", "a/b", ".", "..", "x y", "Ä", "number_sign%"])
def test_label_dir_names_round_trip(label: str) -> None:
    name = label_to_dir(label)
    assert "/" not in name and not name.startswith(".")
    assert dir_to_label(name) == label


def test_write_refuses_non_empty_and_leaves_nothing_on_error(tmp_path: Path) -> None:
    data = tiny_pairs(n=4)
    root = write_paired(tmp_path / "p", data)
    with pytest.raises(TactileBenchError, match="not empty"):
        write_paired(root, data)
    write_paired(root, data.subset([0, 1]), overwrite=True)
    assert len(load_paired(root)) == 2
    bad = DiagnosisPairs(
        data.depth, data.sim, data.real, data.background, None, ["A"] * 4, ["x"] * 4
    )
    with pytest.raises(TactileBenchError, match="twice"):
        write_paired(tmp_path / "q", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p"]  # no temporary leftovers


def test_tactile_diffusion_layout(tmp_path: Path) -> None:
    make_braille_layout(tmp_path / "braille", per_letter=2)
    data = load_paired(tmp_path, size=32)  # found under <root>/braille
    assert len(data) == 6 and data.size == 32
    assert sorted(set(data.labels)) == ["#", "A", "B"]
    assert data.sim_background is not None
    # flat mask -> flat depth 20 * 0.03 mm; sim rendered noise-free over the sim background
    assert torch.allclose(data.depth, torch.full_like(data.depth, 0.6))
    assert data.sim.std(0).max() < 1e-4  # every pair renders the same, no noise
    assert torch.allclose(data.background, torch.full((3, 32, 32), 128.0))


@pytest.mark.parametrize("second", [0, 128])  # the second frame: another, or the same again
def test_tactile_diffusion_pairs_on_several_frames_warn_that_the_first_serves_all(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    second: int,
) -> None:
    """``DiagnosisPairs`` holds one no-contact frame: pairs taken on more than one are warned of."""
    from tactile_bench.data import tactile_diffusion

    load = tactile_diffusion.load_braille_pairs

    def on_two_frames(*args: Any, **kwargs: Any) -> CorpusPairs:
        pairs = load(*args, **kwargs)  # the release has one frame: give half the pairs another
        frames = torch.cat([pairs.real_background, torch.full_like(pairs.real_background, second)])
        index = torch.arange(len(pairs)) % 2
        return replace(pairs, real_background=frames, real_bg_index=index)

    monkeypatch.setattr(tactile_diffusion, "load_braille_pairs", on_two_frames)
    # the CLI's logger stops propagation; let the records reach pytest's handler
    monkeypatch.setattr(logging.getLogger("tactile_bench"), "propagate", True)
    make_braille_layout(tmp_path / "braille", per_letter=1)
    with caplog.at_level(logging.WARNING, logger="tactile_bench.diagnose.paired"):
        data = load_paired(tmp_path, size=16)
    # one record can reach pytest's capture twice (after a CLI test has set up the package's
    # logger); records are counted once each
    records = {id(r): r for r in caplog.records}.values()
    warnings = [r.getMessage() for r in records if r.levelno == logging.WARNING]
    if second == 128:  # equal to the release's grey frame: nothing to say
        assert warnings == []
    else:
        assert len(warnings) == 1
        assert "2 distinct no-contact frames; the first pair's is used for all" in warnings[0]
    assert torch.equal(data.background, torch.full((3, 16, 16), 128.0))  # the first pair's


# ----------------------------------------------------------------------------- bad input
@pytest.fixture
def layout(tmp_path: Path) -> Path:
    return write_paired(tmp_path / "pairs", tiny_pairs(n=6))


def _expect(root: Path, culprit: Path, match: str = "") -> None:
    with pytest.raises(TactileBenchError) as err:
        load_paired(root)
    assert str(culprit) in str(err.value)
    assert match in str(err.value)


def test_missing_pair(layout: Path) -> None:
    victim = layout / "real" / "B" / "p01.png"
    victim.unlink()
    _expect(layout, victim, "missing")


def test_extra_unpaired_file(layout: Path) -> None:
    extra = layout / "sim" / "A" / "zz.png"
    Image.fromarray(np.zeros((32, 32, 3), np.uint8)).save(extra)
    _expect(layout, extra, "unpaired")


def test_size_mismatch(layout: Path) -> None:
    victim = layout / "sim" / "A" / "p03.png"
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(victim)
    _expect(layout, victim, "16 x 16")


def test_background_size_mismatch(layout: Path) -> None:
    victim = layout / "background.png"
    Image.fromarray(np.zeros((30, 30, 3), np.uint8)).save(victim)
    _expect(layout, victim)


def test_truncated_image(layout: Path) -> None:
    victim = layout / "real" / "A" / "p00.png"
    victim.write_bytes(victim.read_bytes()[:60])
    _expect(layout, victim, "not a readable image")


def test_not_an_image(layout: Path) -> None:
    victim = layout / "depth" / "A" / "p00.png"
    victim.write_text("hello")
    _expect(layout, victim, "not a readable image")


def test_wrong_channel_count(layout: Path) -> None:
    victim = layout / "real" / "A" / "p03.png"
    Image.fromarray(np.zeros((32, 32, 4), np.uint8)).save(victim)  # RGBA
    _expect(layout, victim, "4 channel")
    Image.fromarray(np.zeros((32, 32), np.uint8)).save(victim)  # grey
    _expect(layout, victim, "1 channel")


def test_eight_bit_depth(layout: Path) -> None:
    victim = layout / "depth" / "B" / "p01.png"
    Image.fromarray(np.zeros((32, 32), np.uint8)).save(victim)
    _expect(layout, victim, "16-bit")


def test_empty_and_missing_folders(tmp_path: Path) -> None:
    for part in ("depth", "sim", "real"):
        (tmp_path / part).mkdir()
    _expect(tmp_path, tmp_path / "depth", "no PNG")
    (tmp_path / "real").rmdir()
    Image.fromarray(np.zeros((8, 8), np.uint16)).save(tmp_path / "depth" / "a.png")
    _expect(tmp_path, tmp_path / "real", "not found")
    with pytest.raises(TactileBenchError, match="not a paired layout"):
        load_paired(tmp_path / "depth")


def test_missing_background(layout: Path) -> None:
    victim = layout / "background.png"
    victim.unlink()
    _expect(layout, victim, "not found")


def test_non_png_file(layout: Path) -> None:
    stray = layout / "sim" / "A" / "notes.txt"
    stray.write_text("x")
    _expect(layout, stray, "not a .png")
