"""The no-contact frame as evidence for lens effects (issue 42): a lens blurs all it sees,
a gel's geometry changes only where it is pressed."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from tactile_bench.diagnose.candidates import get_candidate
from tactile_bench.diagnose.no_contact import (
    CONFIRMS,
    CONTRADICTS,
    MISSING,
    NO_SIM_FRAME,
    NO_TEXTURE,
    read_frame,
    stored,
)
from tactile_bench.diagnose.ranking import pick_effect
from tactile_bench.diagnose.scene import PairScene, make_scene
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank

SIZE = 32
BLUR = {"sigma_mm": 0.3}  # about 1.1 px across the 18 mm view at 32 px
SPREAD = {"sigma_mm": 1.5, "contact_scale": 0.8}


@pytest.fixture(scope="module")
def scene() -> PairScene:
    """Braille presses with a textured sim no-contact frame (dust, grain: a few grey levels)."""
    data = planted_pairs(build_bank(("A", "L"), BrailleSpec()), {}, 6, 0, SIZE)
    base = make_scene(data)
    gen = torch.Generator().manual_seed(1)
    grain = 12.0 * (torch.rand(base.sim_frame.shape, generator=gen) - 0.5)
    texture = stored(base.sim_frame + grain)
    return dataclasses.replace(base, sim_frame=texture, measured=texture[0], background=texture)


def _measured(scene: PairScene, frame: torch.Tensor) -> PairScene:
    """``scene`` with ``frame`` (1, 3, S, S) as the measured no-contact frame."""
    return dataclasses.replace(scene, measured=frame[0], background=frame)


def _through_lens(scene: PairScene) -> torch.Tensor:
    blur = get_candidate("defocus_blur")
    return stored(blur.through_sensor(scene.sim_frame, BLUR, scene.context(False)))


def test_a_lens_blur_is_credited_on_the_no_contact_frame(scene) -> None:
    reading = read_frame(_measured(scene, _through_lens(scene)), "defocus_blur", BLUR)
    assert reading is not None and reading.status == CONFIRMS
    assert reading.credit > 0.8 and reading.ci_low > 0
    assert reading.gap_after < 0.2 * reading.gap_before


def test_a_gel_spread_leaves_the_frame_so_a_blur_gets_no_credit_there(scene) -> None:
    """Real frames with a spread: the measured frame is the sim's own. The blur that mimics
    the spread on the contacts makes the frame worse; the spread is not scored there."""
    reading = read_frame(scene, "defocus_blur", BLUR)
    assert reading is not None and reading.status == CONTRADICTS
    assert reading.gap_before == 0.0 and reading.ci_high < 0
    assert read_frame(scene, "elastic_spread", SPREAD) is None


def test_without_a_sim_frame_or_texture_the_frame_cannot_read_the_lens(scene) -> None:
    composited = dataclasses.replace(scene, sim_frame_given=False)
    assert read_frame(composited, "defocus_blur", BLUR).status == NO_SIM_FRAME
    smooth = torch.full_like(scene.sim_frame, 120.0)
    flat = _measured(dataclasses.replace(scene, sim_frame=smooth), smooth)
    assert read_frame(flat, "defocus_blur", BLUR).status == NO_TEXTURE


def test_effects_whose_texture_change_no_frame_shows_get_no_reading(scene) -> None:
    """A smooth gain (vignetting) or a blur narrower than a pixel: the texture is no
    evidence either way, and nothing is claimed from it."""
    assert read_frame(scene, "vignetting", {"corner_loss": 0.5}) is None
    assert read_frame(scene, "defocus_blur", {"sigma_mm": 0.01}) is None
    assert read_frame(scene, "camera_noise", {"read_noise": 5.0, "shot_gain": 0.1}) is None


def _options(blur_gap: float, spread_gap: float) -> dict:
    gen = torch.Generator().manual_seed(0)
    jitter = 0.1 * torch.rand(6, generator=gen)
    return {
        "defocus_blur": (BLUR, blur_gap + jitter),
        "elastic_spread": (SPREAD, spread_gap + jitter.flip(0)),
    }


def test_the_frame_names_the_lens_over_a_gel_that_explains_the_contacts_better(scene) -> None:
    before = torch.full((6,), 10.0)
    options = _options(blur_gap=4.0, spread_gap=2.0)
    contacts_only = pick_effect(options, {}, before, 0.2, scene, 0.01, 0).row
    assert contacts_only.effect == "elastic_spread"  # the sim's frame is the measured one
    blurred = _measured(scene, _through_lens(scene))
    row = pick_effect(options, {}, before, 0.2, blurred, 0.01, 0).row
    assert row.effect == "defocus_blur" and row.no_contact.status == CONFIRMS


def test_the_frame_names_the_gel_over_a_lens_it_contradicts(scene) -> None:
    before = torch.full((6,), 10.0)
    options = _options(blur_gap=2.0, spread_gap=4.0)
    blurred = _measured(scene, _through_lens(scene))
    assert pick_effect(options, {}, before, 0.2, blurred, 0.01, 0).row.effect == "defocus_blur"
    row = pick_effect(options, {}, before, 0.2, scene, 0.01, 0).row
    assert row.effect == "elastic_spread" and row.no_contact is None
    assert not any(what in row.separate_by for what in MISSING.values())


def test_where_the_frame_cannot_read_the_lens_both_are_reported(scene) -> None:
    """No sim frame: the better fit on the contacts is named, the other across the lens /
    gel line listed confusable, with the measurement that would separate them."""
    before = torch.full((6,), 10.0)
    composited = dataclasses.replace(scene, sim_frame_given=False)
    row = pick_effect(_options(1.0, 3.0), {}, before, 0.2, composited, 0.01, 0).row
    assert row.effect == "defocus_blur" and row.confusable_with == ["elastic_spread"]
    assert "sim's own no-contact frame" in row.separate_by
    row = pick_effect(_options(3.0, 1.0), {}, before, 0.2, composited, 0.01, 0).row
    assert row.effect == "elastic_spread" and row.confusable_with == ["defocus_blur"]
    # a rival that removes less than a quarter of what is left is not a rival explanation
    row = pick_effect(_options(1.0, 8.0), {}, before, 0.2, composited, 0.01, 0).row
    assert row.confusable_with == []
