"""The YCB-Slide stand-in corpus: shards, split by trajectory, resume, CorpusPairs round trip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_bench.data.corpus import CorpusPairs, load_pairs
from tactile_bench.data.ycb_slide import StandinConfig, build_ycb_slide_standin
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.depth import GelSpec


class StubSensor:
    """A fast stand-in for the surrogate DIGIT: grey background plus depth-coloured red."""

    def background(self, size: int | GelSpec = 64) -> torch.Tensor:
        s = size.size if isinstance(size, GelSpec) else size
        return torch.full((3, s, s), 100.0)

    def render_surface(
        self,
        height: torch.Tensor,
        gel: GelSpec | None = None,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        gel = gel or GelSpec()
        depth = torch.nn.functional.avg_pool2d(height.clamp(min=0), gel.oversample)
        img = torch.full((len(height), 3, gel.size, gel.size), 100.0)
        img[:, 0] += 100 * depth[:, 0]
        return img

    def __repr__(self) -> str:
        return "StubSensor()"


OBJS = ("042_adjustable_wrench", "037_scissors")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("standin")
    manifest = build_ycb_slide_standin(
        root, 40, real_sensor=StubSensor(), seed=0, objects=OBJS, progress=False
    )
    return root, manifest


def test_manifest_and_shards(corpus: tuple[Path, dict]) -> None:
    root, manifest = corpus
    assert json.loads((root / "manifest.json").read_text()) == manifest
    assert manifest["objects"] == list(OBJS)
    assert len(manifest["shards"]) == 2 * 5
    total = 2 * 5 * StandinConfig(40, objects=OBJS).frames_per_trajectory
    assert manifest["n_train"] + manifest["n_test"] + manifest["frames_dropped"] == total
    assert manifest["frames_dropped"] < 0.25 * total  # frames where the sensor would collide
    assert all((root / s["file"]).exists() for s in manifest["shards"])
    assert not (root / ".building").exists()


def test_split_is_by_trajectory(corpus: tuple[Path, dict]) -> None:
    root, manifest = corpus
    train, test = load_pairs(root, "train"), load_pairs(root, "test")
    assert set(train.meta["trajectory"]).isdisjoint(test.meta["trajectory"])
    assert len(test) == manifest["n_test"] and len(train) == manifest["n_train"]
    # one of five trajectories of every object is held out: the paper's 80/20
    assert len(set(test.meta["trajectory"])) == len(OBJS)
    assert set(test.meta["object"]) == {0, 1}


def test_pairs_content(corpus: tuple[Path, dict]) -> None:
    root, _ = corpus
    pairs = load_pairs(root, "all")
    assert pairs.depth.shape[1:] == (1, 64, 64) and pairs.real.dtype == torch.uint8
    assert pairs.sim is not None and pairs.sim.shape == pairs.real.shape
    peak = pairs.depth.flatten(1).amax(1)
    # the press is settled on the mesh: deepest penetration ~= commanded press (area-averaged)
    assert (peak > 0.1).float().mean() > 0.9
    assert (peak <= torch.from_numpy(pairs.meta["press_mm"]) + 1e-3).all()
    assert pairs.meta["velocity_mm_s"].shape == (len(pairs), 2)
    fg = pairs.foreground("real")
    assert fg.shape == pairs.real.shape and abs(float(fg.median()) - 0.5) < 0.01


def test_rerun_reuses_and_resumes(corpus: tuple[Path, dict], tmp_path: Path) -> None:
    root, manifest = corpus
    again = build_ycb_slide_standin(
        root, 40, real_sensor=StubSensor(), seed=0, objects=OBJS, progress=False
    )
    assert again == manifest
    # a killed build: shards of one object on disk, no manifest -> resumes to the same data
    cfg = StandinConfig(n_pairs=20, objects=OBJS[:1])
    full = build_ycb_slide_standin(
        tmp_path / "a", config=cfg, real_sensor=StubSensor(), progress=False
    )
    (tmp_path / "a" / "manifest.json").unlink()
    (tmp_path / "a" / full["shards"][0]["file"]).unlink()
    (tmp_path / "a" / ".building").write_text(full["key"])
    resumed = build_ycb_slide_standin(
        tmp_path / "a", config=cfg, real_sensor=StubSensor(), progress=False
    )
    assert [s["sha256"] for s in resumed["shards"]] == [s["sha256"] for s in full["shards"]]


def test_a_trajectory_without_a_valid_contact_is_an_empty_shard(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A small corpus (two frames a trajectory) can have a trajectory whose every frame would
    collide (``--pairs 100`` on the default objects: the wrench's fifth): the corpus is built
    with that trajectory's shard empty, not refused."""
    from tactile_bench.data import ycb_workers

    real_pairs = ycb_workers.trajectory_pairs

    def colliding_fifth(renderer, traj, *args):  # type: ignore[no-untyped-def]
        *settings, chunks = args  # the fifth trajectory renders no chunk: no valid frame
        return real_pairs(renderer, traj, *settings, range(0) if traj.index == 4 else chunks)

    monkeypatch.setattr(ycb_workers, "trajectory_pairs", colliding_fifth)
    config = StandinConfig(n_pairs=10, objects=OBJS[:1])
    manifest = build_ycb_slide_standin(
        tmp_path, config=config, real_sensor=StubSensor(), progress=False, workers=1
    )
    assert [s["n"] for s in manifest["shards"]] == [2, 2, 2, 2, 0]
    assert manifest["frames_dropped"] == 2
    assert len(load_pairs(tmp_path, "all")) == 8
    # a split whose only trajectory is the empty one is refused by name, not loaded empty
    for shard in manifest["shards"]:
        shard["split"] = "test" if shard["n"] == 0 else "train"
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(TactileBenchError, match="no 'test' pairs"):
        load_pairs(tmp_path, "test")


def test_bad_config_and_files(tmp_path: Path) -> None:
    with pytest.raises(TactileBenchError, match="unknown objects"):
        StandinConfig(objects=("999_anvil",))
    with pytest.raises(TactileBenchError, match="n_pairs"):
        StandinConfig(n_pairs=0)
    with pytest.raises(TactileBenchError, match="manifest.json"):
        load_pairs(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(TactileBenchError, match="manifest.json"):
        load_pairs(tmp_path)


def test_corrupt_shard_is_named(corpus: tuple[Path, dict], tmp_path: Path) -> None:
    root, manifest = corpus
    import shutil

    copy = tmp_path / "c"
    shutil.copytree(root, copy)
    shard = copy / manifest["shards"][0]["file"]
    shard.write_bytes(shard.read_bytes()[:100])
    with pytest.raises(TactileBenchError, match=shard.name):
        load_pairs(copy, "all")


def test_pairset_validates() -> None:
    with pytest.raises(TactileBenchError, match="depth"):
        CorpusPairs(
            torch.zeros(2, 3, 8, 8),
            torch.zeros(2, 3, 8, 8, dtype=torch.uint8),
            torch.zeros(3, 8, 8),
            torch.zeros(2),
        )
    with pytest.raises(TactileBenchError, match="NaN"):
        CorpusPairs(
            torch.full((1, 1, 8, 8), float("nan")),
            torch.zeros(1, 3, 8, 8, dtype=torch.uint8),
            torch.zeros(3, 8, 8),
            torch.zeros(1),
        )
    p = CorpusPairs(
        torch.zeros(4, 1, 8, 8),
        torch.zeros(4, 3, 8, 8, dtype=torch.uint8),
        torch.zeros(3, 8, 8),
        torch.zeros(4),
        meta={"a": np.arange(4)},
    )
    assert len(p.subset([1, 3])) == 2 and list(p.subset([1, 3]).meta["a"]) == [1, 3]


@pytest.mark.slow
def test_default_surrogate_builds(tmp_path: Path) -> None:
    manifest = build_ycb_slide_standin(tmp_path, 20, objects=OBJS[:1], progress=False)
    assert load_pairs(tmp_path, "all").real.float().std() > 0
    assert manifest["n_train"] + manifest["n_test"] == 20 - manifest["frames_dropped"]


def test_settle_probe_moves_only_far_frames() -> None:
    """The peak probe moves frames that start far from their press before the full render;
    frames that start close come out as without it (to float rounding: the last pass's
    residual shift of ~1e-8 mm), and both settle every frame to its press."""
    import trimesh

    from tactile_bench.data.ycb_slide import settle_press
    from tactile_bench.sensor.mesh_depth import MeshDepthRenderer

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    renderer = MeshDepthRenderer.from_trimesh(sphere, GelSpec(size=16))
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down -z onto the sphere's top
    poses[:, :3, 3] = [[0, 0, 19.5], [1, 0, 19.2], [0, 1, 14.0], [0, 0, 25.0]]  # last 2: far
    press = np.array([0.5, 0.8, 0.6, 1.0])
    h_old, p_old, ok_old = settle_press(renderer, poses, press, peak_step=None)
    h_new, p_new, ok_new = settle_press(renderer, poses, press)
    renderer.close()
    assert ok_old.all() and ok_new.all()
    np.testing.assert_allclose(h_new.flatten(1).amax(1).numpy(), press, atol=1e-4)
    torch.testing.assert_close(h_new[:2], h_old[:2], atol=1e-6, rtol=0)
    np.testing.assert_allclose(p_new[:2], p_old[:2], atol=1e-6)
    torch.testing.assert_close(h_new[2:], h_old[2:], atol=1e-4, rtol=0)
