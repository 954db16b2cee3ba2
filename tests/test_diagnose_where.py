"""where(): shares partition the error, and a planted error is found where it was planted."""

from __future__ import annotations

import time

import pytest
import torch

from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.where import analyse_where, band_index, region_masks

SIZE = 32


def _scene(n: int = 24, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, list[str]]:
    """Depth with one square dent per pair (varying place and depth), sim images, labels."""
    g = torch.Generator().manual_seed(seed)
    depth = torch.zeros(n, 1, SIZE, SIZE)
    for i in range(n):
        y, x = torch.randint(6, SIZE - 12, (2,), generator=g).tolist()
        depth[i, 0, y : y + 6, x : x + 6] = 0.2 + 0.2 * (i % 3)
    sim = torch.rand(n, 3, SIZE, SIZE, generator=g) * 200 + 20
    labels = [("A", "B", "C")[i % 3] for i in range(n)]
    return depth, sim, labels


def _data(
    depth: torch.Tensor, sim: torch.Tensor, real: torch.Tensor, labels: list[str]
) -> DiagnosisPairs:
    bg = torch.full((3, SIZE, SIZE), 100.0)
    return DiagnosisPairs(depth, sim, real, bg, None, labels, [str(i) for i in range(len(labels))])


def _shares(result, axis: str) -> dict[str, float]:
    return {p["part"]: p["share"] for p in result.summary["axes"][axis]}


def test_shares_sum_to_one_on_random_error() -> None:
    depth, sim, labels = _scene()
    real = sim + torch.randn(sim.shape, generator=torch.Generator().manual_seed(1)) * 9 + 3
    res = analyse_where(_data(depth, sim, real, labels))
    for axis, parts in res.summary["axes"].items():
        assert sum(p["share"] for p in parts) == pytest.approx(1.0, abs=1e-6), axis
        assert [p["share"] for p in parts] == sorted((p["share"] for p in parts), reverse=True)
    assert set(res.summary["axes"]) == {
        "region",
        "band",
        "channel",
        "consistency",
        "depth",
        "label",
    }
    assert res.summary["mse"] == pytest.approx(float((real - sim).square().mean()), rel=1e-5)
    # white noise: shares follow the amount of area / frequency bins (intensity ~1)
    for part in res.summary["axes"]["region"]:
        assert part["intensity"] == pytest.approx(1.0, abs=0.1)
    assert res.maps["mean_abs"].shape == (SIZE, SIZE)
    assert res.maps["mean_signed"].shape == (3, SIZE, SIZE)


def test_planted_contact_error_in_red_is_found() -> None:
    depth, sim, labels = _scene()
    real = sim.clone()
    real[:, 0] += 40 * (depth[:, 0] > 0)  # red, inside the contact patch only
    res = analyse_where(_data(depth, sim, real, labels))
    region, channel = _shares(res, "region"), _shares(res, "channel")
    assert region["contact"] == pytest.approx(1.0) and channel["R"] == pytest.approx(1.0)
    top = res.summary["axes"]["region"][0]
    assert top["part"] == "contact" and top["intensity"] > 5  # concentrated on a small area
    assert res.maps["mean_signed"][0].max() > 5 and abs(res.maps["mean_signed"][1:]).max() < 1e-4


def test_planted_rim_and_free_gel_errors() -> None:
    depth, sim, labels = _scene()
    masks = region_masks(depth, 0.01, 2)
    real = sim.clone()
    real[:, 2] += 30 * masks[:, 1]  # blue ring around each contact
    res = analyse_where(_data(depth, sim, real, labels), rim_px=2)
    assert _shares(res, "region")["rim"] == pytest.approx(1.0)
    assert _shares(res, "channel")["B"] == pytest.approx(1.0)

    real = sim + 15.0  # a uniform offset: the free gel (most of the area), DC band, same everywhere
    res = analyse_where(_data(depth, sim, real, labels))
    assert res.summary["axes"]["region"][0]["part"] == "free gel"
    assert _shares(res, "band")["DC (uniform offset)"] == pytest.approx(1.0, abs=1e-6)
    assert _shares(res, "consistency")["same in every pair"] == pytest.approx(1.0, abs=1e-6)


def test_planted_frequency_band_label_and_depth() -> None:
    depth, sim, labels = _scene()
    y = torch.arange(SIZE).float()
    stripes = 20 * torch.cos(2 * torch.pi * 6 * y / SIZE)  # 6 cycles per frame, vertical
    real = sim.clone()
    real[:, :, :, :] += stripes[None, None, :, None] * torch.tensor(
        [1.0 if lab == "B" else 0.0 for lab in labels]
    ).view(-1, 1, 1, 1)
    res = analyse_where(_data(depth, sim, real, labels))
    assert _shares(res, "band")["4-8 cyc/frame"] == pytest.approx(1.0, abs=1e-6)
    assert _shares(res, "label")["B"] == pytest.approx(1.0)
    assert _shares(res, "consistency")["varies between pairs"] > 0.5  # only a third of pairs

    deep = (depth.flatten(1).amax(1) > 0.5).view(-1, 1, 1, 1)
    real = sim + 10 * deep * (depth > 0)
    res = analyse_where(_data(depth, sim, real, labels))
    top = res.summary["axes"]["depth"][0]
    assert top["share"] == pytest.approx(1.0) and top["part"].startswith("~0.60")


def test_band_index_covers_every_frequency() -> None:
    index, names = band_index(SIZE, SIZE)
    assert index[0, 0] == 0 and int(index.max()) == len(names) - 1
    assert set(index.unique().tolist()) == set(range(len(names)))


def test_fast_on_a_thousand_pairs() -> None:
    n = 1000
    g = torch.Generator().manual_seed(0)
    depth = torch.zeros(n, 1, 64, 64)
    depth[:, :, 20:30, 20:30] = 0.5
    sim = torch.rand(n, 3, 64, 64, generator=g) * 255
    data = DiagnosisPairs(depth, sim, sim + 1, sim[0], None, ["x"] * n, [str(i) for i in range(n)])
    start = time.perf_counter()
    analyse_where(data)
    assert time.perf_counter() - start < 15
