"""Stand-in YCB objects, sliding trajectories and the mesh depth renderer."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.objects import OBJECTS, YCB_SIZES_MM, object_mesh, object_parts
from tactile_bench.geometry.trajectories import (
    NOISE_ROT_DEG,
    NOISE_TRANS_MM,
    exposed_surface,
    sliding_trajectories,
)
from tactile_bench.sensor.depth import GelSpec, to_depth
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer, embree_available


@pytest.fixture(scope="module")
def all_parts() -> dict[str, list[trimesh.Trimesh]]:
    return {name: object_parts(name, seed=0) for name in OBJECTS}


def test_ten_ycb_slide_objects() -> None:
    assert len(OBJECTS) == 10 and set(OBJECTS) == set(YCB_SIZES_MM)


def test_sizes_match_ycb_within_3_percent(all_parts: dict) -> None:
    for name, parts in all_parts.items():
        ext = trimesh.util.concatenate(parts).extents
        rel = np.abs(ext / np.array(YCB_SIZES_MM[name]) - 1)
        assert rel.max() < 0.03, (name, ext)


def test_every_part_is_closed_and_outward(all_parts: dict) -> None:
    for name, parts in all_parts.items():
        for p in parts:
            assert p.is_watertight, name
            t = p.vertices[p.faces]
            assert np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() > 0, name
    # single-body objects are one closed mesh
    for name in ("004_sugar_box", "005_tomato_soup_can", "055_baseball"):
        assert len(all_parts[name]) == 1


def test_deterministic_under_seed() -> None:
    a = object_mesh("042_adjustable_wrench", seed=3)
    b = object_mesh("042_adjustable_wrench", seed=3)
    c = object_mesh("042_adjustable_wrench", seed=4)
    assert np.array_equal(a.vertices, b.vertices)
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)


def test_unknown_object_is_an_error() -> None:
    with pytest.raises(TactileBenchError, match="unknown object"):
        object_mesh("999_anvil")


@pytest.fixture(scope="module")
def box_trajectories(all_parts: dict) -> list:
    surface = exposed_surface(all_parts["004_sugar_box"])
    return sliding_trajectories(surface, "004_sugar_box", n_trajectories=3, n_frames=400, seed=1)


def test_trajectory_length_and_timing(box_trajectories: list) -> None:
    for tr in box_trajectories:
        assert len(tr) == 400
        path = np.linalg.norm(np.diff(tr.poses[:, :3, 3], axis=0), axis=1).sum()
        assert 440 < path < 560  # 0.5 m slides
        assert tr.time_s[0] == 0 and abs(tr.time_s[-1] - 60.0) < 1e-6
        speed = np.linalg.norm(tr.velocity_mm_s, axis=1)
        assert 4 < speed.mean() < 13  # ~ 500 mm / 60 s
        assert (tr.press_mm >= 0.4 - 1e-6).all() and (tr.press_mm <= 1.2 + 1e-6).all()


def test_poses_are_rigid_and_normal_to_the_surface(box_trajectories: list, all_parts: dict) -> None:
    surface = exposed_surface(all_parts["004_sugar_box"])
    for tr in box_trajectories:
        rot = tr.poses[:, :3, :3]
        assert np.allclose(rot @ rot.transpose(0, 2, 1), np.eye(3), atol=1e-6)
        assert np.allclose(np.linalg.det(rot), 1.0, atol=1e-6)
        n = surface.normal(tr.poses[:, :3, 3])
        cos = np.einsum("ij,ij->i", rot[:, :, 2], n)
        assert np.median(cos) < -0.99  # z points into the object (tilt <= a few degrees)


def test_pose_noise_statistics(box_trajectories: list) -> None:
    rel = np.concatenate([np.linalg.inv(t.poses) @ t.measured for t in box_trajectories])
    trans = rel[:, :3, 3]
    assert abs(trans.std() - NOISE_TRANS_MM) < 0.05
    assert abs(trans.mean()) < 0.05
    angle = np.degrees(
        np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1))
    )
    # the angle of three independent N(0, s) Euler angles: rms = sqrt(3) s
    assert abs(np.sqrt((angle**2).mean()) - np.sqrt(3) * NOISE_ROT_DEG) < 0.15


def _box_pose(press: float, top: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down: z into the box
    pose[:3, 3] = [0.0, 0.0, top - press]
    return pose


@pytest.mark.parametrize("backend", ["embree", "pybullet"])
def test_flat_box_pressed_by_d_gives_uniform_depth(backend: str) -> None:
    if backend == "embree" and not embree_available():
        pytest.skip("embreex not installed")
    gel = GelSpec()
    box = trimesh.creation.box(extents=(100, 100, 20))
    renderer = MeshDepthRenderer.from_trimesh(box, gel, backend=backend)
    poses = np.stack([_box_pose(d, 10.0) for d in (0.3, 0.8, 1.5)])
    height = renderer.render_height(poses)
    renderer.close()
    assert height.shape == (3, 1, 128, 128)
    depth = to_depth(height, gel)
    for k, d in enumerate((0.3, 0.8, 1.5)):
        assert torch.allclose(depth[k], torch.full_like(depth[k], d), atol=1e-4)


def test_no_contact_and_edges() -> None:
    box = trimesh.creation.box(extents=(10, 100, 20))  # narrower than the 18 mm gel width
    renderer = MeshDepthRenderer.from_trimesh(box)
    away = _box_pose(-30.0, 10.0)  # 30 mm above the box: beyond reach
    h = renderer.render_height(np.stack([_box_pose(0.5, 10.0), away]))
    assert (h[1] == -renderer.reach_mm).all()
    row = h[0, 0, 64]
    inside = torch.isclose(row, torch.tensor(0.5), atol=1e-4)
    assert 60 < inside.sum() < 80  # 10 of 18 mm of the width: ~71 of 128 pixels


def test_bad_inputs_are_errors() -> None:
    box = trimesh.creation.box()
    renderer = MeshDepthRenderer.from_trimesh(box)
    with pytest.raises(TactileBenchError, match="4, 4"):
        renderer.render_height(np.zeros((2, 3, 4)))
    bad = np.tile(np.eye(4), (1, 1, 1))
    bad[0, 0, 3] = np.nan
    with pytest.raises(TactileBenchError, match="NaN"):
        renderer.render_height(bad)
    with pytest.raises(TactileBenchError, match="orthonormal"):
        renderer.render_height(np.eye(4) * 2)
    with pytest.raises(TactileBenchError, match="backend"):
        MeshDepthRenderer.from_trimesh(box, backend="opengl")
    with pytest.raises(TactileBenchError, match="faces"):
        MeshDepthRenderer(np.zeros((3, 3)), np.zeros((0, 3)))


@pytest.mark.parametrize("backend", ["embree", "pybullet"])
def test_peak_height_is_the_max_over_its_sub_grid(backend: str) -> None:
    """The settle probe casts every step-th pixel's ray: its max is that sub-grid's max of
    the full render, so never above the full render's peak."""
    if backend == "embree" and not embree_available():
        pytest.skip("embreex not installed")
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    renderer = MeshDepthRenderer.from_trimesh(sphere, GelSpec(size=16), backend=backend)
    poses = np.stack([_box_pose(d, 20.0) for d in (0.5, 1.5, -30.0)])
    poses[0, :3, 3] += [3.0, -2.0, 0.0]
    full = renderer.render_height(poses)
    peak = renderer.peak_height(poses, 4)
    renderer.close()
    expected = full[:, 0, 2::4, 2::4].flatten(1).amax(1).double().numpy()
    np.testing.assert_allclose(peak, expected, atol=1e-5)
    assert (peak <= full.flatten(1).amax(1).double().numpy() + 1e-6).all()
    assert peak[2] == -renderer.reach_mm  # nothing within reach
