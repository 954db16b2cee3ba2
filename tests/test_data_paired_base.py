"""``data.paired.Pairs``, the one base of the paired containers: its shape checks name the
field, ``subset`` takes positions, masks and slices, ``foreground`` is the one formula."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch

from tactile_bench.data.ball_presses import BallPresses
from tactile_bench.data.braille import BrailleSet
from tactile_bench.data.corpus import CorpusPairs
from tactile_bench.data.paired import Pairs
from tactile_bench.data.pixels import image_to_foreground
from tactile_bench.diagnose.paired import DiagnosisPairs, from_braille_set
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry import Poses

N, S = 5, 8


@dataclass
class Toy(Pairs):
    """The smallest container: the base's fields, per-pair names and an optional sim."""

    OPTIONAL: ClassVar[frozenset[str]] = frozenset({"sim"})

    depth: torch.Tensor
    sim: torch.Tensor | None
    real: torch.Tensor
    sim_background: torch.Tensor
    real_background: torch.Tensor
    names: list[str]

    def __post_init__(self) -> None:
        self._check_pairs(names=self.names)

    def _subset_own(self, index: torch.Tensor | slice) -> dict[str, Any]:
        return {"names": [self.names[i] for i in self._positions(index)]}


def _images(n: int = N, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (n, 3, S, S), generator=g, dtype=torch.uint8)


def _toy(**changes: Any) -> Toy:
    parts: dict[str, Any] = {
        "depth": torch.arange(N, dtype=torch.float32)[:, None, None, None].expand(N, 1, S, S),
        "sim": _images(seed=1),
        "real": _images(seed=2),
        "sim_background": torch.full((3, S, S), 100, dtype=torch.uint8),
        "real_background": torch.full((3, S, S), 140, dtype=torch.uint8),
        "names": [f"p{i}" for i in range(N)],
    }
    return Toy(**(parts | changes))


@pytest.mark.parametrize(
    ("field", "value", "says"),
    [
        ("depth", torch.zeros(N, 3, S, S), "depth must be (N,1,S,S), got (5, 3, 8, 8)"),
        ("depth", torch.zeros(N, S, S), "depth must be (N,1,S,S)"),
        ("sim", torch.zeros(N, 3, S, 4), "sim must be (N,3,S,S) = (5, 3, 8, 8), got"),
        ("real", torch.zeros(N - 1, 3, S, S), "real must be (N,3,S,S) = (5, 3, 8, 8), got"),
        ("real", torch.zeros(N, 1, S, S), "real must be (N,3,S,S)"),
        ("sim_background", torch.zeros(1, 3, S, S), "sim_background must be (3,S,S) = (3, 8, 8)"),
        ("real_background", torch.zeros(3, 4, 4), "real_background must be (3,S,S)"),
        ("names", ["a"], "names must have one entry per pair (N = 5), got 1"),
        ("real", None, "real is missing (None)"),
    ],
)
def test_shape_errors_name_the_field(field: str, value: Any, says: str) -> None:
    with pytest.raises(TactileBenchError) as info:
        _toy(**{field: value})
    assert str(info.value).startswith(f"Toy: {field} ")
    assert says in str(info.value)


def test_optional_fields_may_be_none_and_say_so_when_asked_for() -> None:
    toy = _toy(sim=None)
    assert toy.subset([0, 1]).sim is None
    with pytest.raises(TactileBenchError, match="Toy: no sim images in this set"):
        toy.foreground("sim")


def test_len_is_the_number_of_pairs() -> None:
    assert len(_toy()) == N and len(_toy().subset(slice(0, 0))) == 0


@pytest.mark.parametrize(
    "idx",
    [
        [3, 1],
        torch.tensor([3, 1]),
        np.array([3, 1]),
    ],
)
def test_subset_by_positions_keeps_their_order(idx: Any) -> None:
    toy = _toy()
    sub = toy.subset(idx)
    assert isinstance(sub, Toy) and sub.names == ["p3", "p1"]
    for name in ("depth", "sim", "real"):
        assert torch.equal(getattr(sub, name), getattr(toy, name)[[3, 1]])
    assert sub.real_background is toy.real_background  # frames are shared, not copied


def test_subset_by_mask_and_by_slice() -> None:
    toy = _toy()
    mask = torch.tensor([True, False, True, False, True])
    for idx in (mask, mask.numpy(), slice(0, None, 2)):
        sub = toy.subset(idx)
        assert sub.names == ["p0", "p2", "p4"]
        assert torch.equal(sub.real, toy.real[[0, 2, 4]])
        assert torch.equal(sub.depth[:, 0, 0, 0], torch.tensor([0.0, 2.0, 4.0]))


def test_a_mask_of_the_wrong_length_is_an_error() -> None:
    with pytest.raises(TactileBenchError, match=r"Toy.subset: a mask of shape \(4,\) for 5 pairs"):
        _toy().subset(torch.ones(4, dtype=torch.bool))


def test_foreground_is_the_one_formula() -> None:
    toy = _toy()
    for kind in ("sim", "real"):
        want = image_to_foreground(
            getattr(toy, kind).float(), getattr(toy, f"{kind}_background").float()
        )
        got = toy.foreground(kind)
        assert got.dtype == torch.float32 and torch.equal(got, want)
    assert torch.equal(toy.foreground(), toy.foreground("real"))
    with pytest.raises(TactileBenchError, match="Toy.foreground: kind must be 'sim' or 'real'"):
        toy.foreground("depth")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- containers
def _poses(n: int = N) -> Poses:
    zeros = torch.zeros(n)
    return Poses(torch.arange(n) % 3, zeros, zeros + 1, zeros + 2, torch.linspace(0.1, 0.5, n))


def test_braille_set_subsets_and_foregrounds_through_the_base() -> None:
    toy = _toy()
    bset = BrailleSet(
        toy.depth,
        toy.sim,
        toy.real,
        _poses().labels,
        _poses(),
        toy.sim_background,
        toy.real_background,
    )
    assert isinstance(bset, Pairs) and BrailleSet.subset is Pairs.subset
    mask = torch.tensor([False, True, False, True, True])
    for idx in (mask, [1, 3, 4], slice(1, None)):
        sub = bset.subset(idx)
        want = torch.tensor([1, 3, 4]) if not isinstance(idx, slice) else torch.arange(1, N)
        assert torch.equal(sub.labels, bset.labels[want])
        assert torch.equal(sub.poses.press_mm, bset.poses.press_mm[want])
        assert torch.equal(sub.sim, bset.sim[want])
    with pytest.raises(TactileBenchError, match=r"BrailleSet.subset: a mask of shape \(2,\)"):
        bset.subset([True, False])
    for kind in ("sim", "real"):
        assert torch.equal(bset.foreground(kind), toy.foreground(kind))
    with pytest.raises(TactileBenchError, match="BrailleSet: poses must have one entry per pair"):
        BrailleSet(
            toy.depth,
            toy.sim,
            toy.real,
            _poses().labels,
            _poses(2),
            toy.sim_background,
            toy.real_background,
        )


def test_braille_set_file_is_read_back_as_before(tmp_path: Path) -> None:
    toy = _toy()
    poses = _poses()
    bset = BrailleSet(
        toy.depth, toy.sim, toy.real, poses.labels, poses, toy.sim_background, toy.real_background
    )
    back = BrailleSet.load(bset.save(tmp_path / "set.npz")).subset([4, 0])
    assert torch.equal(back.real, toy.real[[4, 0]]) and torch.equal(
        back.labels, poses.labels[[4, 0]]
    )
    assert torch.equal(back.real_background, toy.real_background)


def test_pair_set_subsets_and_foregrounds_through_the_base() -> None:
    toy = _toy()
    frames = torch.stack([toy.real_background, toy.real_background // 2])  # (B,3,S,S)
    which = torch.tensor([0, 1, 1, 0, 1])
    pairs = CorpusPairs(toy.depth, toy.real, frames, which, meta={"t": np.arange(N) * 10})
    assert isinstance(pairs, Pairs) and CorpusPairs.subset is Pairs.subset
    for idx in (torch.tensor([False, True, True, False, False]), [1, 2], slice(1, 3)):
        sub = pairs.subset(idx)
        assert list(sub.meta["t"]) == [10, 20] and sub.real_bg_index.tolist() == [1, 1]
        assert torch.equal(sub.real, toy.real[1:3]) and sub.sim is None
    with pytest.raises(TactileBenchError, match=r"CorpusPairs.subset: a mask of shape \(6,\)"):
        pairs.subset(torch.ones(6, dtype=torch.bool))
    want = image_to_foreground(toy.real.float(), frames[which].float())
    assert torch.equal(pairs.foreground("real"), want)  # each pair on its own frame
    with pytest.raises(TactileBenchError, match="CorpusPairs: no sim images in this set"):
        pairs.foreground("sim")
    with pytest.raises(
        TactileBenchError, match=r"CorpusPairs: real_background must be \(B,3,S,S\)"
    ):
        CorpusPairs(toy.depth, toy.real, torch.zeros(2, 3, S, 4), which)
    with pytest.raises(
        TactileBenchError, match="CorpusPairs: meta 't' must have one entry per pair"
    ):
        CorpusPairs(toy.depth, toy.real, frames, which, meta={"t": np.arange(3)})


def test_paired_data_subsets_and_foregrounds_through_the_base() -> None:
    toy = _toy()
    real_bg = toy.real_background.float()
    data = DiagnosisPairs(
        toy.depth, toy.sim.float(), toy.real.float(), real_bg, None, list("abcde"), toy.names
    )
    assert isinstance(data, Pairs) and DiagnosisPairs.subset is Pairs.subset
    for idx in (torch.tensor([False, False, True, True, False]), [2, 3], slice(2, 4)):
        sub = data.subset(idx)  # a mask selects (it was once read as positions 0 and 1)
        assert sub.labels == ["c", "d"] and sub.names == ["p2", "p3"]
        assert torch.equal(sub.sim, toy.sim[2:4].float()) and sub.gel_mm == data.gel_mm
    assert torch.equal(data.foreground("real"), image_to_foreground(data.real, real_bg))
    with pytest.raises(TactileBenchError, match="DiagnosisPairs: no sim background in this set"):
        data.foreground("sim")
    with pytest.raises(TactileBenchError, match=r"DiagnosisPairs: background must be \(3,S,S\)"):
        DiagnosisPairs(toy.depth, data.sim, data.real, real_bg[None], None, data.labels, data.names)
    with pytest.raises(
        TactileBenchError, match="DiagnosisPairs: names must have one entry per pair"
    ):
        DiagnosisPairs(toy.depth, data.sim, data.real, real_bg, None, data.labels, ["x"])


def _presses(**changes: Any) -> BallPresses:
    """N presses at a 4:3 size (H != W: the packs' frames are not square); no sim images."""
    toy = _toy()
    parts: dict[str, Any] = {
        "depth": toy.depth[..., :6],
        "real": toy.real[..., :6].float(),
        "background": toy.real_background[..., :6].float(),
        "centres_px": np.arange(2 * N, dtype=np.float64).reshape(N, 2),
        "radii_px": np.arange(N, dtype=np.float64) + 10,
        "pixmm": 0.05,
        "frame_hw": (480, 640),
        "ball_radius_mm": 2.0,
        "sensor": "gelsight",
        "source": Path("pack"),
    }
    return BallPresses(**(parts | changes))


def test_ball_presses_subset_and_foreground_through_the_base() -> None:
    presses = _presses()
    assert isinstance(presses, Pairs) and BallPresses.subset is Pairs.subset
    assert len(presses) == N and presses.index.tolist() == list(range(N))
    for idx in (torch.tensor([False, True, False, True, False]), [1, 3], slice(1, 4, 2)):
        sub = presses.subset(idx)
        assert sub.names == ["press001", "press003"] and sub.radii_px.tolist() == [11.0, 13.0]
        assert sub.centres_px.tolist() == [[2.0, 3.0], [6.0, 7.0]]
        assert torch.equal(sub.real, presses.real[[1, 3]]) and sub.background is presses.background
        assert (sub.pixmm, sub.frame_hw, sub.gel_mm) == (0.05, (480, 640), presses.gel_mm)
    again = presses.subset([3, 1]).subset([1])  # pack positions survive a second subset
    assert again.names == ["press001"] and again.index.tolist() == [1]
    want = image_to_foreground(presses.real, presses.background)
    assert torch.equal(presses.foreground(), want)
    assert presses.sim is None
    with pytest.raises(TactileBenchError, match="BallPresses: no sim images in this set"):
        presses.foreground("sim")
    with pytest.raises(TactileBenchError, match=r"BallPresses: background must be \(3,S,S\)"):
        _presses(background=torch.zeros(3, S, S))
    with pytest.raises(TactileBenchError, match="BallPresses: radii_px must have one entry per"):
        _presses(radii_px=np.ones(N - 1))


def test_a_braille_set_and_its_paired_data_have_the_same_foregrounds() -> None:
    toy, poses = _toy(), _poses()
    bset = BrailleSet(
        toy.depth, toy.sim, toy.real, poses.labels, poses, toy.sim_background, toy.real_background
    )
    data = from_braille_set(bset, "ABC")
    for kind in ("sim", "real"):
        assert torch.equal(data.foreground(kind), bset.foreground(kind))
