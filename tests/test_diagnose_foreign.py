"""The foreign renderer: independent of the project's sensor code, seeded, plants visible."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_bench.diagnose import foreign
from tactile_bench.diagnose.foreign import (
    FOREIGN_PLANTS,
    SHADINGS,
    SINGLE_PLANTS,
    VARIANTS,
    foreign_pairs,
    shared_real_available,
)
from tactile_bench.effects import EFFECTS
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import BrailleSpec
from tactile_bench.sensor.heightfield import build_bank

SIZE, N, SEED = 32, 4, 3
FORBIDDEN = (
    "tactile_bench.effects",
    "tactile_bench.sensor.optics",
    "tactile_bench.sensor.surrogate",
    "tactile_bench.sensor.background",
    "tactile_bench.sensor.response_fit",
    "tactile_bench.diagnose.candidates",
    "tactile_bench.diagnose.gapfit",
    "tactile_bench.diagnose.which",
)
needs_real = pytest.mark.skipif(
    not shared_real_available(), reason="shared real DIGIT references (../shared/real) absent"
)


@pytest.fixture(scope="module")
def bank():
    return build_bank(("A", "L", "#"), BrailleSpec())


def _params(name: str, seed: int = 0) -> dict[str, float]:
    return FOREIGN_PLANTS[name].draw(np.random.default_rng(seed))


def _pairs(bank, plant=None, shading="lambert", variant="own", seed=SEED, params=None):
    p = params if params is not None else (_params(plant) if plant else {})
    return foreign_pairs(bank, plant, p, N, seed, SIZE, shading, variant)


def _imported_modules(path: Path) -> set[str]:
    """Every module foreign.py imports, with ``from a import b`` also giving ``a.b``."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_imports_none_of_the_projects_renderer_code() -> None:
    modules = _imported_modules(Path(foreign.__file__))
    assert "tactile_bench.diagnose.paired" in modules  # the parse did find the imports
    bad = [m for m in modules for f in FORBIDDEN if m == f or m.startswith(f + ".")]
    assert not bad, bad
    assert not any(m.split(".")[-1] in ("gapfit", "which", "candidates") for m in modules)


def test_expected_names_are_catalogue_effects() -> None:
    for name in SINGLE_PLANTS:
        plant = FOREIGN_PLANTS[name]
        assert plant.expected is None or plant.expected in EFFECTS, plant
        assert plant.kind == ("out_of_catalogue" if plant.expected is None else "single")
        assert plant.parts == (name,)
    assert FOREIGN_PLANTS["barrel"].expected is None
    assert FOREIGN_PLANTS["chromatic"].expected is None
    assert sum(FOREIGN_PLANTS[p].expected is not None for p in SINGLE_PLANTS) == 9


def test_a_lens_blur_blurs_the_no_contact_frame_and_adds_noise_after(bank) -> None:
    """The combined plants are their parts applied together: the lens blur's no-contact
    frame is the blur plant's (the same lens), its frames the blur's plus noise."""
    assert FOREIGN_PLANTS["lens_blur"].parts == ("blur", "noise")
    assert FOREIGN_PLANTS["blur_elastic"].named_as == ("defocus_blur", "elastic_spread")
    params = _params("lens_blur")
    sigma = {"sigma_px": params["sigma_px"]}
    lens = _pairs(bank, "lens_blur", params=params)
    blur = _pairs(bank, "blur", params=sigma)
    assert torch.equal(lens.background, blur.background)  # the no-contact frame: blurred
    noise = (lens.real - blur.real).std()
    assert 1.0 < float(noise) < 3 * params["read_noise"] + 5  # noise after the blur


@pytest.mark.parametrize("name", list(FOREIGN_PLANTS))
def test_draws_are_seeded_and_in_their_ranges(name: str) -> None:
    a, b = _params(name, 5), _params(name, 5)
    assert a == b and a != _params(name, 6)
    assert all(isinstance(v, float) and np.isfinite(v) for v in a.values())


def test_lambert_render_is_plausible_and_plant_free_real_equals_sim(bank) -> None:
    d = _pairs(bank)
    assert d.sim.shape == d.real.shape == (N, 3, SIZE, SIZE)
    assert d.depth.shape == (N, 1, SIZE, SIZE) and d.background.shape == (3, SIZE, SIZE)
    means = d.background.mean((1, 2))
    assert 120 <= float(means.mean()) <= 170 and float(means.max() - means.min()) > 5
    assert torch.equal(d.sim, d.sim.round()) and torch.equal(d.real, d.sim)
    assert torch.equal(d.background, d.sim_background)
    contact = (d.depth > 0).expand_as(d.sim)
    assert (d.sim - d.background).abs()[contact].mean() > 3  # contacts are visible
    assert len(d.labels) == N and set(d.labels) <= {"A", "L", "#"}


@pytest.mark.parametrize("name", list(FOREIGN_PLANTS))
def test_each_plant_changes_real_only_and_is_deterministic(bank, name: str) -> None:
    base, planted = _pairs(bank), _pairs(bank, name)
    assert (planted.real - base.real).abs().max() >= 2, name
    assert torch.equal(planted.sim, base.sim)  # the sim side never sees the plant
    assert torch.equal(planted.sim_background, base.sim_background)
    again = _pairs(bank, name)
    assert torch.equal(again.real, planted.real) and torch.equal(
        again.background, planted.background
    )


def test_composited_sim_is_the_sim_change_on_the_measured_frame(bank) -> None:
    own, comp = _pairs(bank, "gain"), _pairs(bank, "gain", variant="composited")
    assert comp.sim_background is None and own.sim_background is not None
    assert torch.equal(comp.real, own.real) and torch.equal(comp.background, own.background)
    change_own = own.sim - own.sim_background
    change_comp = comp.sim - comp.background
    assert (change_comp - change_own).abs().max() <= 1  # rounding only
    assert not torch.equal(comp.sim, own.sim)  # the gain plant makes the frames differ


def test_vignetting_darkens_the_measured_corners(bank) -> None:
    ratio = _pairs(bank, "vignetting").background / _pairs(bank).background
    corners = ratio[:, [0, 0, -1, -1], [0, -1, 0, -1]].mean()
    centre = ratio[:, SIZE // 2 - 2 : SIZE // 2 + 2, SIZE // 2 - 2 : SIZE // 2 + 2].mean()
    assert corners < centre - 0.1


def test_noise_leaves_the_measured_frame_clean(bank) -> None:
    base, noisy = _pairs(bank), _pairs(bank, "noise")
    assert torch.equal(noisy.background, base.background)
    outside = (noisy.depth == 0).expand_as(noisy.real)
    assert (noisy.real - base.real)[outside].std() > 2
    assert not torch.equal(_pairs(bank, "noise", seed=SEED + 1).real[0], noisy.real[0])


def test_shift_moves_the_contact_by_the_drawn_offset(bank) -> None:
    params = {"length_px": 2.0 * 64 / SIZE, "angle_deg": 0.0}  # 2 px to the right here
    base, shifted = _pairs(bank), _pairs(bank, "shift", params=params)
    change, change_shifted = base.real - base.background, shifted.real - shifted.background
    moved = torch.roll(change, 2, dims=-1)  # no contact touches the image edge here
    assert (change_shifted - moved).abs().mean() < 0.3 * (change_shifted - change).abs().mean()


@pytest.mark.parametrize(
    ("kwargs", "listed"),
    [
        ({"plant": "smudge"}, "blur"),
        ({"shading": "phong"}, "polycalib"),
        ({"variant": "tacto"}, "composited"),
    ],
)
def test_bad_names_raise_one_line(bank, kwargs: dict, listed: str) -> None:
    args = {"plant": None, "shading": "lambert", "variant": "own"} | kwargs
    with pytest.raises(TactileBenchError, match=listed) as err:
        foreign_pairs(bank, args["plant"], {}, N, SEED, SIZE, args["shading"], args["variant"])
    assert "\n" not in str(err.value)


def test_missing_params_raise(bank) -> None:
    with pytest.raises(TactileBenchError, match="sigma_px"):
        foreign_pairs(bank, "blur", {}, N, SEED, SIZE)


def test_missing_shared_folder_raises(bank, tmp_path: Path) -> None:
    assert not shared_real_available(tmp_path)
    with pytest.raises(TactileBenchError, match=str(tmp_path)):
        foreign_pairs(bank, None, {}, N, SEED, SIZE, "polycalib", real_dir=tmp_path)
    assert SHADINGS == ("lambert", "polycalib") and VARIANTS == ("own", "composited")


@needs_real
def test_polycalib_uses_the_real_background_and_shows_contacts(bank) -> None:
    d = _pairs(bank, shading="polycalib")
    means = d.background.mean((1, 2))
    assert torch.allclose(means, torch.tensor([99.3, 105.2, 98.8]), atol=3)  # the real DIGIT
    contact = (d.depth > 0).expand_as(d.sim)
    assert (d.sim - d.background).abs()[contact].mean() > 5
    assert ((d.sim - d.background)[~contact] == 0).float().mean() > 0.8  # flat gel: no change


@needs_real
@pytest.mark.parametrize("name", ["optics", "gain", "vignetting", "elastic"])
def test_polycalib_plants_change_real(bank, name: str) -> None:
    base, planted = _pairs(bank, shading="polycalib"), _pairs(bank, name, shading="polycalib")
    assert (planted.real - base.real).abs().max() >= 2
    assert torch.equal(planted.sim, base.sim)
    comp = _pairs(bank, name, shading="polycalib", variant="composited")
    assert comp.sim_background is None
    unclipped = (comp.sim > 0) & (comp.sim < 255)
    gap = (comp.sim - comp.background) - (base.sim - base.sim_background)
    assert gap[unclipped].abs().max() <= 1
