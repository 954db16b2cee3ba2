"""calibrate's contact-region refit of the gel geometry (calibrate/geometry.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tactile_bench.calibrate.geometry import (
    contact_cv_error,
    profile_surface,
    refit_geometry,
    refittable,
)
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.validate import planted_pairs
from tactile_bench.effects import EFFECTS
from tactile_bench.effects.optics import sensor_optics
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.response_fit import (
    fit_response,
    pair_normal_equations,
    predict_delta,
    solve_response,
)

SIZE = 24
GEL = (18.88, 14.16)
SPREAD = {"sigma_mm": 1.0, "contact_scale": 0.4}


def _pairs(spread: dict[str, float] | None) -> DiagnosisPairs:
    """12 braille pairs whose 'real' frames are the GelSight lookup on the gel surface a
    profile with ``spread`` (None: no spread) renders, noise-free."""
    data = planted_pairs(build_bank(("A", "L"), BrailleSpec()), {}, 12, 5, SIZE)
    effects = {} if spread is None else {"elastic_spread": spread}
    surface = profile_surface(data.depth, effects, GEL)
    weights = sensor_optics("gelsight")[0].numpy()
    real = data.background[None] + predict_delta(surface, weights, GEL)
    return dataclasses.replace(data, real=real.clamp(0, 255), gel_mm=GEL)


@pytest.fixture(scope="module")
def spread_pairs() -> DiagnosisPairs:
    return _pairs(SPREAD)


def test_per_pair_normal_equations_sum_to_the_full_fit(spread_pairs: DiagnosisPairs) -> None:
    data = spread_pairs
    surface = profile_surface(data.depth, {}, GEL)
    delta = data.real - data.background[None]
    xtx, xty = pair_normal_equations(surface, delta, GEL)
    assert xtx.shape[0] == xty.shape[0] == len(data)
    assert xtx.dtype == torch.float64
    whole = fit_response(surface, delta, GEL)
    summed = solve_response(xtx.sum(0), xty.sum(0))
    # float32 products summed in another order: the weights agree to a fraction of a percent
    # (the solve is ill-conditioned), the renders they make to hundredths of a grey level
    np.testing.assert_allclose(summed, whole, rtol=0.02, atol=0.02)
    a, b = predict_delta(surface, summed, GEL), predict_delta(surface, whole, GEL)
    assert float((a - b).abs().max()) < 0.05


def test_the_spread_the_real_frames_have_is_found(spread_pairs: DiagnosisPairs) -> None:
    """Started without a spread, the refit offers the unselected effect and lands near the
    planted one; the CV error it reports falls, and the planted value scores near zero."""
    effects, record = refit_geometry(spread_pairs, {"optical_response": {"blend": 1.0}})
    assert "elastic_spread" in effects and "optical_response" in effects
    assert effects["elastic_spread"]["sigma_mm"] == pytest.approx(SPREAD["sigma_mm"], abs=0.1)
    assert record["cv_contact_mse_after"] < 0.2 * record["cv_contact_mse_before"]
    folds = [torch.arange(k, len(spread_pairs), 4) for k in range(4)]
    planted = contact_cv_error(spread_pairs, {"elastic_spread": SPREAD}, folds)
    assert planted < 0.05 * record["cv_contact_mse_before"]
    assert any(key.startswith("elastic_spread.sigma_mm") for key in record["tried"])


def test_a_selected_spread_too_wide_is_brought_back() -> None:
    """The diagnosis's whole-frame choice (here the bound, 3 mm) is replaced by the
    contact region's."""
    data = _pairs(SPREAD)
    start = {"elastic_spread": {"sigma_mm": 3.0, "contact_scale": 0.4}}
    effects, _ = refit_geometry(data, start)
    assert effects["elastic_spread"]["sigma_mm"] < 1.5


def test_no_spread_in_the_frames_leaves_none_in_the_profile() -> None:
    effects, record = refit_geometry(_pairs(None), {"optical_response": {"blend": 1.0}})
    assert "elastic_spread" not in effects  # neutral (sigma 0) wins: not carried
    assert record["cv_contact_mse_after"] <= record["cv_contact_mse_before"]


def test_only_deterministic_geometry_is_refitted() -> None:
    names = refittable()
    assert names, "the catalogue has a deterministic geometry candidate"
    for name in names:
        assert EFFECTS[name].acts_on == "geometry" and not EFFECTS[name].stochastic


def test_pairs_without_contact_leave_the_geometry_as_selected() -> None:
    """No contact region to judge by: every value ties, and a tie keeps what was selected."""
    data = _pairs(None)
    flat = dataclasses.replace(data, depth=torch.zeros_like(data.depth))
    start = {"elastic_spread": {"sigma_mm": 3.0, "contact_scale": 0.4}}
    effects, _ = refit_geometry(flat, start)
    assert effects == start
