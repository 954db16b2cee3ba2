"""The downstream part of "how far": noise matching of the training sets, the export protocol."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from tactile_bench.cli import main
from tactile_bench.diagnose.paired import load_paired
from tactile_bench.diagnose.shrink import how_far, match_noise
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.metrics import estimate_pixel_noise
from tactile_bench.sensor.heightfield import build_bank


def _frames(noise: tuple[float, float, float], n: int = 64, seed: int = 5) -> torch.Tensor:
    """Foregrounds: a flat gel at 0.5 with one bright square (a contact) and white noise."""
    g = torch.Generator().manual_seed(seed)
    x = torch.full((n, 3, 32, 32), 0.5)
    x[:, :, 10:16, 12:18] += 0.2
    return x + torch.tensor(noise)[None, :, None, None] * torch.randn(x.shape, generator=g)


def test_match_noise_raises_a_clean_set_to_the_real_level() -> None:
    real_std = torch.tensor([0.01, 0.02, 0.008])
    clean = _frames((0.002, 0.002, 0.002))
    out, own, added = match_noise(clean, real_std, copies=3, seed=0)
    assert out.shape == (3 * len(clean), 3, 32, 32)
    assert torch.allclose(own, torch.full((3,), 0.002), rtol=0.15)
    measured = estimate_pixel_noise(out[: len(clean)])
    assert torch.allclose(measured, real_std, rtol=0.1)
    assert not torch.equal(out[: len(clean)], out[len(clean) : 2 * len(clean)])  # fresh draws
    again, _, _ = match_noise(clean, real_std, copies=3, seed=0)
    assert torch.equal(out, again)  # seeded


def test_match_noise_leaves_a_noisier_set_alone() -> None:
    noisy = _frames((0.03, 0.03, 0.03))
    out, own, added = match_noise(noisy, torch.tensor([0.01, 0.01, 0.01]), copies=2, seed=0)
    assert torch.equal(added, torch.zeros(3))
    assert torch.equal(out, torch.cat([noisy, noisy]))
    few, own, added = match_noise(noisy[:4], torch.tensor([0.01, 0.01, 0.01]), copies=1, seed=0)
    assert torch.isnan(own).all() and torch.equal(added, torch.zeros(3))  # too few to tell
    assert torch.equal(few, noisy[:4])


def test_export_pairs_protocols_differ(tmp_path: Path) -> None:
    common = ["--generate", "12", "--chars", "L", "--size", "32", "--no-progress"]
    roots = {}
    for protocol in ("classifier", "finetune"):
        roots[protocol] = tmp_path / protocol
        args = ["export-pairs", *common, "--protocol", protocol, "--out", str(roots[protocol])]
        assert main(args) == 0
    upright, turned = (load_paired(roots[p]).depth for p in ("classifier", "finetune"))
    assert upright.shape == turned.shape == (12, 1, 32, 32)

    def spread(depth: torch.Tensor) -> float:
        """How far the contacts' centres lie from the image centre, px (median)."""
        ys, xs = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
        w = depth[:, 0] / depth[:, 0].sum((1, 2), keepdim=True)
        cx, cy = (w * xs).sum((1, 2)), (w * ys).sum((1, 2))
        return float(torch.hypot(cx - 15.5, cy - 15.5).median())

    # +-3 mm against +-5 mm offsets: the classifier grid keeps contacts nearer the centre
    assert spread(upright) < spread(turned)
    assert main(["export-pairs", *common, "--protocol", "nope", "--out", str(tmp_path / "x")]) == 2


def test_plain_sim_trains_over_the_sims_own_no_contact_frame() -> None:
    """A sim whose every frame is the real one moved by a constant, with its own no-contact
    frame moved alike, has the real foregrounds: its classifier is the real one's."""
    data = planted_pairs(build_bank(("A", "L"), BrailleSpec()), {}, 24, 3, 16)
    offset = torch.tensor([30.0, -20.0, 10.0])[:, None, None]
    moved = dataclasses.replace(
        data, sim=data.real + offset, sim_background=data.background + offset
    )
    fit, held = torch.arange(0, 24, 2), torch.arange(1, 24, 2)
    downstream = how_far(moved, fit, held, {}, seed=0).downstream
    assert downstream.plain_sim_accuracy == downstream.real_accuracy
