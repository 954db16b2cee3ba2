"""``bench --only jpeg``: ours, kornia's and libjpeg on a couple of frames; the section's
shape, that errors and rates mean what they say, and that the verdict is the numbers'."""

from __future__ import annotations

import statistics

import pytest
import torch

from tactile_bench.bench.jpeg import CODECS, codecs, describe_kornia_padding, jpeg_section

QUALITIES = (30, 90)


@pytest.fixture(scope="module")
def section() -> dict:
    """Two stored frames and one native one, one repetition: every setting and codec."""
    return jpeg_section(n=2, n_native=1, qualities=QUALITIES, repeats=1)


def _rows(section: dict, setting: str, codec: str) -> dict[int, dict]:
    return {
        r["quality"]: r for r in section["rows"] if r["setting"] == setting and r["codec"] == codec
    }


def test_every_setting_quality_and_codec_is_measured(section: dict) -> None:
    assert list(section["settings"]) == ["stored", "effect", "native"]
    assert section["settings"]["effect"]["coded_hw"] == [320, 240]
    assert section["frames"]["stored"] == 2 and section["frames"]["native"] == 1
    assert len(section["rows"]) == 3 * len(QUALITIES) * len(CODECS)
    for row in section["rows"]:
        assert row["images_per_s"] > 0 and row["forward"]["median_wall_s"] > 0
        if row["codec"] == "libjpeg":  # not differentiable: no backward figure
            assert row["fwd_bwd_images_per_s"] is None
        else:
            assert row["fwd_bwd_images_per_s"] > 0
    assert section["threads"] == torch.get_num_threads()


def test_errors_are_against_libjpeg_and_shrink_with_quality(section: dict) -> None:
    for setting in section["settings"]:
        for q, row in _rows(section, setting, "libjpeg").items():
            # the reference against itself: a second encode of the same frames
            assert row["mae_vs_libjpeg"] == 0 and row["psnr_vs_libjpeg"] is None, (setting, q)
        for codec in CODECS:
            rows = _rows(section, setting, codec)
            # every codec moves the frame less at quality 90 than at 30
            assert rows[90]["mae_vs_input"] < rows[30]["mae_vs_input"], (setting, codec)
        for codec in ("ours", "kornia"):
            for row in _rows(section, setting, codec).values():
                # both approximate libjpeg: a wrong range (0..1 vs 0..255) would be far off
                assert row["psnr_vs_libjpeg"] > 35, (setting, codec, row["quality"])
    for codec in ("ours", "kornia"):  # in the effect's path, closer to libjpeg at 90
        rows = _rows(section, "effect", codec)
        assert rows[90]["mae_vs_libjpeg"] < rows[30]["mae_vs_libjpeg"], codec


def test_the_verdict_is_computed_from_the_rows(section: dict, bench_markdown) -> None:
    assert section["headline"] == "effect"
    s = section["summary"]["effect"]
    ours, kornia = _rows(section, "effect", "ours"), _rows(section, "effect", "kornia")
    ratios = [ours[q]["images_per_s"] / kornia[q]["images_per_s"] for q in QUALITIES]
    assert s["ours_over_kornia_forward"] == pytest.approx(statistics.median(ratios))
    errors = [ours[q]["mae_vs_libjpeg"] for q in QUALITIES]
    assert s["ours_mae_vs_libjpeg"] == pytest.approx(statistics.fmean(errors))
    md = bench_markdown(jpeg=section)
    assert "## JPEG codecs: ours against kornia's, libjpeg the reference" in md
    verdict = next(line for line in md.splitlines() if line.startswith("**Verdict**"))
    assert f"{s['ours_over_kornia_forward']:.1f}x kornia's forward speed" in verdict
    assert f"at {s['ours_mae_vs_libjpeg']:.2f} grey levels" in verdict
    assert f"{s['ours_over_kornia_forward_backward']:.1f}x its forward+backward" in verdict
    closer = s["ours_mae_vs_libjpeg"] < s["kornia_mae_vs_libjpeg"]
    assert ("closer to libjpeg" in verdict) == closer
    assert "nothing was padded" in md


def test_the_differentiable_codecs_pass_a_gradient() -> None:
    x = torch.linspace(0, 255, 2 * 3 * 32 * 32).view(2, 3, 32, 32).requires_grad_(True)
    for name in ("ours", "kornia"):
        x.grad = None
        codecs((64, 48))[name](x, 60).square().mean().backward()
        assert x.grad is not None and x.grad.abs().sum() > 0, name


def test_kornia_padding_is_named_from_the_sizes() -> None:
    assert "nothing was padded" in describe_kornia_padding([(64, 64), (320, 240)])
    assert "60 x 50 -> 64 x 64" in describe_kornia_padding([(64, 64), (60, 50)])
