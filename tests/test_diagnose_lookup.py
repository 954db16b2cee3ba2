"""The optical response as a lookup fitted from the pairs, and the pairs' own gel view."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_bench.diagnose.paired import load_paired, write_paired
from tactile_bench.diagnose.scene import fit_reference, make_scene
from tactile_bench.diagnose.simulate import apply_effects, lookup_for
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.effects.optics import sensor_optics
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.response_fit import predict_delta

SIZE = 32


@pytest.fixture(scope="module")
def foreign_sensor_pairs():
    """Braille pairs whose 'real' sensor answers light like the GelSight, not our DIGIT."""
    bank = build_bank(("A", "L", "#"), BrailleSpec())
    data = planted_pairs(bank, {}, 48, 5, SIZE)
    weights = sensor_optics("gelsight")[0].numpy()
    real = data.background[None] + predict_delta(data.depth, weights, data.gel_mm)
    return dataclasses.replace(data, real=real.round().clamp(0, 255))


def test_the_lookup_is_fitted_on_the_fit_split_and_nothing_else(foreign_sensor_pairs) -> None:
    data = foreign_sensor_pairs
    fit, held = torch.arange(0, 24), torch.arange(24, 48)
    table = lookup_for(make_scene(data, held, fit_reference(data, fit)), {})
    scrambled = dataclasses.replace(data, real=data.real.clone())
    scrambled.real[held] = 255 - scrambled.real[held]  # held-out frames must not matter
    again = lookup_for(make_scene(scrambled, held, fit_reference(scrambled, fit)), {})
    torch.testing.assert_close(table, again)
    without = make_scene(data, held)
    with pytest.raises(TactileBenchError, match="no fitted lookup"):
        lookup_for(without, {})


def test_a_sensor_that_is_not_our_digit_is_named_by_its_optical_response(
    foreign_sensor_pairs,
) -> None:
    data = foreign_sensor_pairs
    fit, held = torch.arange(0, 48, 2), torch.arange(1, 48, 2)
    result = explain_gap(data, fit, held, seed=0, progress=False)
    assert result.ranking and result.ranking[0].effect == "optical_response"
    assert result.ranking[0].shrink > 0.8 and result.unexplained < 0.2
    assert np.asarray(result.response_table).shape == (22, 3, 6)
    after = apply_effects(data, result.selected_params, held, 0, fit)
    assert float(((after - data.real[held]) ** 2).mean()) < 0.2 * float(
        ((data.sim[held] - data.real[held]) ** 2).mean()
    )


def test_the_gel_view_travels_with_the_pairs(tmp_path: Path, foreign_sensor_pairs) -> None:
    data = dataclasses.replace(foreign_sensor_pairs.subset(range(4)), gel_mm=(18.88, 14.16))
    write_paired(tmp_path / "p", data)
    assert json.loads((tmp_path / "p" / "gel.json").read_text())["height_mm"] == 14.16
    assert load_paired(tmp_path / "p").gel_mm == (18.88, 14.16)
    (tmp_path / "p" / "gel.json").write_text('{"width_mm": -1, "height_mm": 3}')
    with pytest.raises(TactileBenchError, match="gel.json: width_mm, height_mm must be"):
        load_paired(tmp_path / "p")
    digit = foreign_sensor_pairs.subset(range(4))
    write_paired(tmp_path / "d", digit)
    assert not (tmp_path / "d" / "gel.json").exists()
    assert load_paired(tmp_path / "d").gel_mm == (18.0, 24.0)
