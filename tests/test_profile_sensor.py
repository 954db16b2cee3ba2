"""A profile that brings its own sensor: the registry, the ``sensor:`` block, write_profile,
pickling into a spawned worker, scoring a profile on a paired folder (``ground --pairs``)."""

from __future__ import annotations

import json
import multiprocessing
import pickle
import shutil
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.cli import main
from tactile_bench.diagnose.paired import DiagnosisPairs, write_paired
from tactile_bench.effects.sensors import (
    BUILTIN_SENSORS,
    SensorFit,
    is_sensor,
    register_sensor,
    sensor_fit,
)
from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.provenance import InputHasher
from tactile_bench.pipeline.recipe import load_recipe
from tactile_bench.pipeline.runner import stage_key
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.pair_scoring import score_profile
from tactile_bench.sensor.profile_io import write_profile
from tactile_bench.sensor.surrogate import SurrogateDigit

#: the gelsight profile's effects (sensor/profiles/gelsight.yaml)
EFFECTS = {
    "elastic_spread": {"sigma_mm": 1.2},
    "optical_response": {},
    "camera_noise": {"read_noise": 2.13, "shot_gain": 0.0},
}


def _own_sensor(dc_shift: float = 0.0) -> dict[str, Any]:
    """The GelSight's numbers as a user's sensor block (its field's DC term moved)."""
    block = sensor_fit("gelsight").to_dict()
    block["background_dct"][0][0][0] += dc_shift
    return block


def _height(n: int = 2, side: int = 32) -> torch.Tensor:
    """Signed heights (n, 1, side, side): a dome pressed 0.5 mm, shifted per frame."""
    t = torch.linspace(-1, 1, side)
    yy, xx = torch.meshgrid(t, t, indexing="ij")
    domes = [(0.6 - ((xx - 0.2 * i) ** 2 + yy**2)).clamp(min=0) for i in range(n)]
    return (torch.stack(domes)[:, None] * 1.4 - 0.2).float()


def _render(sensor: SurrogateDigit, size: int = 16) -> torch.Tensor:
    gel = sensor.gel(size)
    return sensor.render_surface(_height(), gel, torch.Generator().manual_seed(1))


def test_builtins_are_registered_under_their_names() -> None:
    assert set(BUILTIN_SENSORS) == {"digit", "gelsight", "gelsight-mini"}
    assert sensor_fit("digit").gel_mm == (18.0, 24.0)
    assert tuple(sensor_fit("gelsight").response_weights.shape) == (22, 3, 6)
    with pytest.raises(TactileBenchError, match="unknown sensor 'nope'"):
        sensor_fit("nope")


def test_registry_round_trip_and_two_calibrations_of_one_name() -> None:
    a = SensorFit.from_mapping("mine", _own_sensor(), "a.yaml")
    b = SensorFit.from_mapping("mine", _own_sensor(12.0), "b.yaml")
    key_a, key_b = register_sensor(a), register_sensor(b)
    assert key_a.startswith("mine@") and key_b.startswith("mine@") and key_a != key_b
    assert sensor_fit(key_a) is a and is_sensor(key_b)
    # the same numbers again: the same key, the first object kept
    again = SensorFit.from_mapping("mine", a.to_dict(), "c.yaml")
    assert register_sensor(again) == key_a and sensor_fit(key_a) is a
    assert torch.equal(again.response_weights, a.response_weights)
    # both live in one process: each renders its own field, caches never mix them
    sa = SurrogateDigit(EFFECTS, "mine", "a", sensor_fit=a)
    sb = SurrogateDigit(EFFECTS, "mine", "b", sensor_fit=b)
    first = sa.background(16)
    other = sb.background(16)
    assert (other - first)[0].mean() > 5.0  # the moved DC term of red
    assert torch.equal(sa.background(16), first)


def test_write_profile_loads_and_renders_as_its_source_fit(tmp_path: Path) -> None:
    source = SurrogateDigit.from_profile("gelsight")
    path = write_profile(
        tmp_path / "mine.yaml",
        name="mine",
        description="my GelSight",
        effects=EFFECTS,
        sensor=sensor_fit("gelsight").to_dict(),
    )
    loaded = SurrogateDigit.from_profile(path)
    assert loaded.name == "mine" and loaded.unit.startswith("mine@")
    assert loaded.sensor == loaded.unit and loaded.effects_enabled == source.effects_enabled
    assert loaded.gel(16) == source.gel(16)
    assert torch.equal(_render(loaded), _render(source))
    assert torch.equal(loaded.background(16), source.background(16))
    # from a SensorFit too, and the profile's own copies keep the sensor
    fit = SensorFit.from_mapping("mine", sensor_fit("gelsight").to_dict(), "x")
    again = write_profile(
        tmp_path / "fit.yml", name="mine", description="", effects=EFFECTS, sensor=fit
    )
    assert SurrogateDigit.from_profile(again).unit == loaded.unit
    assert torch.equal(
        _render(loaded.without("camera_noise")), _render(source.without("camera_noise"))
    )


def test_write_profile_refuses_before_writing(tmp_path: Path) -> None:
    bad = _own_sensor()
    bad["led_azimuth_deg"] = [1.0, 2.0]
    with pytest.raises(TactileBenchError, match=r"bad\.yaml: sensor\.led_azimuth_deg"):
        write_profile(tmp_path / "bad.yaml", name="m", description="", effects={}, sensor=bad)
    with pytest.raises(TactileBenchError, match=r"effects\.nope: unknown effect"):
        write_profile(
            tmp_path / "bad.yaml", name="m", description="", effects={"nope": {}}, sensor=None
        )
    with pytest.raises(TactileBenchError, match=r"ends in \.yaml"):
        write_profile(tmp_path / "bad.txt", name="m", description="", effects={}, sensor=None)
    assert not list(tmp_path.iterdir())


def _profile_text(block: Any) -> str:
    return (
        "name: mine\nunit: mine\neffects: {optical_response: {}}\n" + "sensor: " + json.dumps(block)
    )


def _weights_21() -> dict[str, Any]:
    block = _own_sensor()
    block["response_weights"] = block["response_weights"][:21]
    return block


def _with(key: str, value: Any) -> dict[str, Any]:
    return _own_sensor() | {key: value}


def _without(key: str) -> dict[str, Any]:
    return {k: v for k, v in _own_sensor().items() if k != key}


BAD_BLOCKS = {
    "unknown key": (_own_sensor() | {"gain": 1.0}, "sensor.gain: unknown key"),
    "missing key": (_without("gel_mm"), "sensor.gel_mm: missing"),
    "wrong shape": (_weights_21(), "sensor.response_weights: must be 22 x 3 x 6"),
    "ragged dct": (_with("background_dct", [[[1.0, 2.0]], [[1.0]], [[1.0]]]), "background_dct"),
    "text number": (_with("led_azimuth_deg", ["1", 2.0, 3.0]), "sensor.led_azimuth_deg"),
    "negative gel": (_with("gel_mm", [18.0, -1.0]), "sensor.gel_mm: width and height"),
    "not a mapping": ([1, 2], "sensor: must be a mapping"),
}


@pytest.mark.parametrize("case", sorted(BAD_BLOCKS))
def test_a_bad_sensor_block_is_one_line_naming_file_and_key(tmp_path: Path, case: str) -> None:
    block, words = BAD_BLOCKS[case]
    path = tmp_path / "mine.yaml"
    path.write_text(_profile_text(block))
    with pytest.raises(TactileBenchError) as err:
        SurrogateDigit.from_profile(path)
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(path)) and words in message


def test_non_finite_numbers_and_a_bad_unit_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(_profile_text(_own_sensor()).replace("[18.88, 14.16]", "[18.88, .nan]"))
    with pytest.raises(TactileBenchError, match=r"mine\.yaml: sensor\.gel_mm: must be finite"):
        SurrogateDigit.from_profile(path)
    path.write_text(_profile_text(_own_sensor()).replace("unit: mine", "unit: my/sensor"))
    with pytest.raises(TactileBenchError, match=r"mine\.yaml: unit: 'my/sensor' is not a sensor"):
        SurrogateDigit.from_profile(path)
    path.write_text(_profile_text(_own_sensor()).replace("unit: mine\n", "sensors: 1\n"))
    with pytest.raises(TactileBenchError, match=r"mine\.yaml: sensors: unknown key"):
        SurrogateDigit.from_profile(path)


def test_check_reads_a_profile_with_its_own_sensor(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_profile(
        tmp_path / "good.yaml", name="m", description="", effects=EFFECTS, sensor=_own_sensor()
    )
    assert main(["check", str(good)]) == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text(_profile_text(_weights_21()))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "sensor.response_weights" in err


def test_a_pickled_profile_registers_its_sensor_in_a_spawned_worker(tmp_path: Path) -> None:
    """A fresh process does not know the key: the unpickled profile brings its fit."""
    sensor = SurrogateDigit(
        EFFECTS, "spawned", "s", sensor_fit=SensorFit.from_mapping("spawned", _own_sensor(3.0), "x")
    ).without("camera_noise")
    height = _height(1, 24)
    expected = sensor.render_surface(height, sensor.gel(12), None, stochastic=False)
    copy = pickle.loads(pickle.dumps(sensor))
    assert copy.unit == sensor.unit
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        got = pool.apply(sensor.render_surface, (height, sensor.gel(12), None, None, False))
    assert torch.equal(got, expected)


def test_a_stage_cache_key_follows_the_profile_file_content(tmp_path: Path) -> None:
    profile = tmp_path / "prof.yaml"
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: t\nstages:\n  - name: braille\n    kind: braille_data\n"
        "    config: {chars: AB, n_finetune: 4, n_test: 4, real_sensor: prof.yaml}\n"
    )

    def key() -> str:
        loaded = load_recipe(recipe)
        stage = loaded.stage("braille")
        files = InputHasher(tmp_path / "run", tmp_path).config_files(
            stage.config.model_dump(mode="json")
        )
        return stage_key(loaded, stage, {}, files)

    def write(dc: float) -> None:
        write_profile(profile, name="m", description="", effects=EFFECTS, sensor=_own_sensor(dc))

    write(0.0)
    first = key()
    write(0.0)  # rewritten, same content: the same key
    assert key() == first
    write(7.5)
    assert key() != first


def _tiny_folder(root: Path, gel_mm: tuple[float, float]) -> Path:
    """Four 32 x 32 pairs whose 'real' frames the gelsight profile rendered."""
    real_sensor = SurrogateDigit.from_profile("gelsight")
    depth = _height(4, 32).clamp(min=0)
    gel = GelSpec(*gel_mm, 32, 1)
    real = real_sensor.render_surface(depth, gel, torch.Generator().manual_seed(2))
    data = DiagnosisPairs(
        depth=depth,
        sim=real,
        real=real,
        background=real_sensor.background(gel),
        sim_background=None,
        labels=[""] * 4,
        names=[f"p{i}" for i in range(4)],
        gel_mm=gel_mm,
    )
    return write_paired(root, data)


def test_ground_pairs_writes_the_json_it_promises(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _tiny_folder(tmp_path / "pairs", sensor_fit("gelsight").gel_mm)
    out = tmp_path / "g.json"
    args = ["ground", "--profile", "gelsight", "--pairs", str(folder), "--size", "16"]
    assert main([*args, "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert set(report) == {"n_pairs", "sim", "profile"} and report["n_pairs"] == 4
    for row in ("sim", "profile"):
        assert set(report[row]) == {"mse", "ssim", "contact_mse"}
    # the frames are the profile's own renders: it is far closer than the plain simulator
    assert report["profile"]["mse"] < 0.5 * report["sim"]["mse"]
    assert "profile gelsight against 4 pairs" in capsys.readouterr().out
    # a profile YAML with its own sensor (the GelSight's numbers) scores the same folder
    own = write_profile(
        tmp_path / "own.yaml", name="own", description="", effects=EFFECTS, sensor=_own_sensor()
    )
    assert (
        main(
            [
                "ground",
                "--profile",
                str(own),
                "--pairs",
                str(folder),
                "--size",
                "16",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    assert json.loads(out.read_text()) == report
    # sim/ is optional: the folder's sim images are not used
    shutil.rmtree(folder / "sim")
    assert main([*args, "--json", str(out)]) == 0
    assert json.loads(out.read_text()) == report


def test_ground_pairs_refuses_a_folder_without_depth_or_of_another_gel(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "nodepth"
    (empty / "real").mkdir(parents=True)
    assert main(["ground", "--profile", "gelsight", "--pairs", str(empty)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "depth" in err
    digit = _tiny_folder(tmp_path / "digit", (18.0, 24.0))
    assert main(["ground", "--profile", "gelsight", "--pairs", str(digit), "--size", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "18 x 24" in err and "18.88 x 14.16" in err


def test_score_profile_checks_its_tensors() -> None:
    sensor = SurrogateDigit.from_profile("gelsight")
    depth, real, bg = torch.zeros(2, 1, 32, 32), torch.zeros(2, 3, 16, 16), torch.zeros(3, 16, 16)
    scored = score_profile(sensor, depth, real, bg, (18.88, 14.16), size=16)
    assert scored["n_pairs"] == 2 and len(scored["per_frame"]["profile"]) == 2
    with pytest.raises(TactileBenchError, match="background must be"):
        score_profile(sensor, depth, real, bg[:, :8], (18.88, 14.16), size=16)
    with pytest.raises(TactileBenchError, match="real must be"):
        score_profile(sensor, depth, real[:1], bg, (18.88, 14.16), size=16)
