"""Which way is up: our rendered depth against a real frame's contact, by the original's rule.

Tactile-Diffusion pairs real DIGIT frames with TACTO heightmaps it rotates by 180 degrees first
(``save_hm``: ``cv2.flip`` on both axes, ``ycb_slide_sim/modules/misc.py``): TACTO's camera
is the gel frame turned half a turn about its normal (``tacto_camera_axes``), and the flip
undoes it. So in a frame, image columns run along the gel's +x and rows along its -y
(YCB-Slide's gel frame, z out of the object): the view from the camera behind the gel. A
synthetic log over a wedge, whose contact is lopsided, has frames drawn by that rule; our
loader's depth (``_FLIP`` in ``data/ycb_slide.py``) must lie the same way. A symmetric object
could not tell a flip from none: the wedge can, on each axis.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from data.original_layouts import tacto_camera_axes, write_braille_release, write_ycb_slide_wedge

from tactile_bench.data.tactile_diffusion import load_braille_pairs
from tactile_bench.data.ycb_real import load_ycb_slide_real
from tactile_bench.sensor.depth import GelSpec


def _corr(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.flatten().double(), b.flatten().double()
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / (a.norm() * b.norm()))


def _variants(depth: torch.Tensor) -> dict[str, torch.Tensor]:
    return {
        "as rendered": depth,
        "rows flipped": depth.flip(-2),
        "columns flipped": depth.flip(-1),
        "rotated 180": depth.flip(-2, -1),
    }


def test_tacto_camera_is_the_gel_turned_half_a_turn() -> None:
    assert np.allclose(tacto_camera_axes(), np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


def test_rendered_depth_lies_as_the_real_frame_on_a_wedge(tmp_path: Path) -> None:
    # clean_up_optitrack flags a step > 10x the running mean: it needs 11 steps to judge
    log = write_ycb_slide_wedge(tmp_path, n_frames=14, glitch=12)
    pairs = load_ycb_slide_real(tmp_path, gel=GelSpec(size=32))
    assert 12 not in pairs.meta["frame"].tolist() and len(pairs) == 13  # the jump is dropped
    assert int(pairs.real_background.float().mean().round()) == 110  # released bgs/bg_0.jpg
    contact = (
        (pairs.real.float() - pairs.real_background[0].float())
        .mul(torch.tensor([60.0, 30.0, -40.0])[:, None, None] / 6100.0)
        .sum(1)
    )  # back to mm: the fixture drew depth x (60, 30, -40)
    for k in range(len(pairs)):
        scores = {name: _corr(v[k, 0], contact[k]) for name, v in _variants(pairs.depth).items()}
        best = max(scores, key=scores.get)
        assert best == "as rendered" and scores[best] > 0.9, scores
        assert scores["rotated 180"] < 0  # TACTO's own map (before save_hm) would be wrong
    # the depth's scale agrees too: the press is 0.7 mm at the gel centre, the drawn map's max
    assert abs(float(pairs.depth.amax()) - float(np.max(log["depth"]))) < 0.1


@pytest.mark.parametrize("letter", ["a", "#"])
def test_braille_masks_pair_with_their_frames_as_stored(tmp_path: Path, letter: str) -> None:
    """``dataio_braille.py`` flips neither the mask nor the frame: neither do we."""
    braille = write_braille_release(tmp_path / "datasets", per_letter=2)
    pairs = load_braille_pairs(braille, {letter: ["0.jpg"]}, GelSpec(size=32))
    contact = (
        (pairs.real.float() - pairs.real_background.float())
        .mul(torch.tensor([2.0, 1.0, -1.0])[:, None, None])
        .sum(1)
    )
    scores = {name: _corr(v[0, 0], contact[0]) for name, v in _variants(pairs.depth).items()}
    assert max(scores, key=scores.get) == "as rendered" and scores["as rendered"] > 0.9, scores
