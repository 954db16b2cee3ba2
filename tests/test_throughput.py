"""Throughput entry points, and the fast rendering paths against their reference versions."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tactile_bench.bench.throughput import braille_throughput, format_report, object_throughput
from tactile_bench.effects import EFFECTS, EffectContext
from tactile_bench.effects.camera import jpeg_approx
from tactile_bench.effects.kernels import area_pool, blur_matrices, gaussian_blur
from tactile_bench.effects.optics import new_scene
from tactile_bench.geometry.braille import BrailleSpec, braille_mesh
from tactile_bench.geometry.contacts import classifier_protocol
from tactile_bench.sensor.depth import GelSpec, affine_grid, render_height, sample_maps
from tactile_bench.sensor.heightfield import build_bank, raycast_heights
from tactile_bench.sensor.mesh_depth import MeshDepthRenderer, embree_available
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.timing import SpanTimer, timed_span

CHARS = ("A", "Y", "#")
needs_embree = pytest.mark.skipif(not embree_available(), reason="embreex not installed")


@pytest.fixture(scope="module")
def bank():
    return build_bank(CHARS)


def _check_report(report: dict, n: int) -> None:
    assert report["n"] == n and report["wall_s"] > 0 and report["cpu_s"] > 0
    assert report["per_s"] == pytest.approx(n / report["wall_s"])
    assert set(report["spans"]) == set(report["spans_cpu"])
    assert all(v >= 0 for v in report["spans"].values())
    # exclusive span times plus the untimed rest add up to the wall time
    assert sum(report["spans"].values()) == pytest.approx(report["wall_s"], rel=0.05)
    assert len(report["load"]) == 3 and report["threads"] == torch.get_num_threads()


def test_braille_throughput_reports_every_span() -> None:
    report = braille_throughput(8, seed=1)
    _check_report(report, 8)
    spans = report["spans"]
    for name in ("bank", "sim.height", "sim.depth", "sim.optics", "real.height", "io", "uint8"):
        assert spans[name] > 0, name
    for effect in EFFECTS.values():  # the default profile has every effect on
        assert f"real.{effect.acts_on}.{effect.name}" in spans
    text = format_report("braille", report)
    assert text.startswith("braille: 8 in") and "sim.optics" in text


def test_object_throughput_reports_every_span() -> None:
    report = object_throughput(10, objects=("042_adjustable_wrench",), workers=1)
    assert report["n"] + report["frames_dropped"] == 10
    _check_report(report, report["n"])
    for name in ("objects", "surface", "trajectories", "mesh_bvh", "height.rays", "settle"):
        assert report["spans"][name] > 0, name
    with pytest.raises(Exception, match="n must be"):
        object_throughput(3)


def test_span_timer_is_exclusive_and_off_by_default(monkeypatch) -> None:
    import types

    from tactile_bench.sensor import timing

    ticks = iter(range(100))  # a fake clock: every reading is one second later
    fake = types.SimpleNamespace(perf_counter=lambda: next(ticks), thread_time=lambda: 0.0)
    monkeypatch.setattr(timing, "time", fake)
    with timed_span("nobody.listens"):  # no timer active: nothing recorded, the clock not read
        pass
    with SpanTimer() as timer, timed_span("outer"):  # reads 0 ... 5
        with timed_span("inner"):  # reads 1 ... 2
            pass
        with timed_span("inner"):  # reads 3 ... 4
            pass
    assert dict(timer.wall) == {"inner": 2.0, "outer": 3.0}  # 5 s in all, 2 of them inside


# ------------------------------------------------------------ fast paths vs references
def test_sparse_sim_shading_equals_dense(bank) -> None:
    optics, gel = SimOptics(), GelSpec()
    poses = classifier_protocol(CHARS).index(torch.arange(0, 60, 7))
    depth = F.avg_pool2d(render_height(bank, poses, gel).clamp(min=0), 2)
    assert 0 < float((depth > 0).float().mean()) < 0.2  # a braille contact: sparse path
    flat = optics.shade(torch.zeros(1, 1, 64, 64), gel)
    reference = optics.shade(depth, gel) - flat
    torch.testing.assert_close(optics.shade_change(depth, gel), reference, atol=1e-3, rtol=0)
    dense = depth + 0.3  # everything touched: the dense path
    torch.testing.assert_close(
        optics.shade_change(dense, gel), optics.shade(dense, gel) - flat, atol=1e-3, rtol=0
    )
    # render = blur(change * scale) + background (+ noise): check against the pieces
    bg = torch.rand(3, 64, 64) * 200
    image = optics.render(depth, bg, None, gel)
    assert image.shape == (len(poses), 3, 64, 64)
    change = (image - bg).abs()
    assert float(change[:, :, 20:40, 20:40].amax()) > 1 and float(change.amin()) == 0


def test_sim_noise_does_not_depend_on_the_batch_split() -> None:
    optics, bg = SimOptics(), torch.full((3, 64, 64), 100.0)
    depth = torch.zeros(40, 1, 64, 64)
    whole = optics.render(depth, bg, torch.Generator().manual_seed(3))
    g = torch.Generator().manual_seed(3)
    parts = torch.cat([optics.render(depth[:16], bg, g), optics.render(depth[16:], bg, g)])
    assert torch.equal(whole, parts)


def test_render_height_fast_paths(bank) -> None:
    theta = torch.randn(5, 2, 3)
    reference = F.affine_grid(theta, [5, 1, 32, 32], align_corners=False)
    torch.testing.assert_close(affine_grid(theta, 32), reference, atol=1e-5, rtol=0)
    gel = GelSpec(size=32)
    poses = classifier_protocol(CHARS).index(torch.arange(0, 80))  # repeats placements
    height = render_height(bank, poses, gel)
    offset = (bank.top_max[poses.labels] - poses.press_mm).view(-1, 1, 1, 1)
    assert torch.equal(height, sample_maps(bank, poses, gel, 256, 64) - offset)
    x = torch.rand(3, 2, 12, 12)
    assert torch.equal(area_pool(x, 2), F.avg_pool2d(x, 2))
    assert torch.equal(area_pool(x, 3), F.avg_pool2d(x, 3))


@pytest.mark.parametrize("sigma", [(0.7, 0.5), (6.4, 4.8), (9.0, 17.0)])
def test_factored_blur_equals_its_matrices(sigma: tuple[float, float]) -> None:
    x = torch.rand(2, 1, 64, 64)
    my, mx = blur_matrices(64, 64, *sigma)
    expected = my @ x @ mx.T
    torch.testing.assert_close(gaussian_blur(x, *map(torch.tensor, sigma)), expected)


@pytest.mark.parametrize(
    ("shape", "sigma"), [((2, 1, 128, 128), (1.6, 1.2)), ((3, 3, 64, 64), (0.43, 0.32))]
)
def test_narrow_blur_by_taps_equals_the_matrices(shape: tuple, sigma: tuple) -> None:
    """Narrow blurs (radius <= 5 px) run as shifted adds: the same blur as the matrices."""
    from tactile_bench.effects.kernels import small_blur_taps

    assert small_blur_taps(shape[2], shape[3], *sigma, 64) is not None  # the taps path
    x = torch.rand(*shape) * 255
    my, mx = blur_matrices(shape[2], shape[3], *sigma)
    got = gaussian_blur(x, *map(torch.tensor, sigma))
    torch.testing.assert_close(got, my @ x @ mx.T, atol=1e-4, rtol=1e-6)
    # fitted sigmas keep the differentiable matrices
    s = torch.tensor(sigma[0], requires_grad=True)
    gaussian_blur(x, s, torch.tensor(sigma[1])).sum().backward()
    assert s.grad is not None and torch.isfinite(s.grad)


@pytest.mark.parametrize("size", [128, 64])
def test_elastic_spread_in_place_equals_autograd_path(size: int) -> None:
    """The in-place spread (no autograd) gives the differentiable path's floats: all three
    pyramid levels (pooled GEMM, dense GEMM, taps) at 128 px, fewer at 64."""
    gen = torch.Generator().manual_seed(3)
    x = torch.nn.functional.avg_pool2d(torch.randn(4, 1, size + 8, size + 8, generator=gen), 9, 1)
    x = x * 0.5 - 0.1
    effect, ctx = EFFECTS["elastic_spread"], EffectContext(18.0, 24.0)
    fast = effect.apply(x, {}, None, ctx)
    slow = effect.apply(x.clone().requires_grad_(), {}, None, ctx)
    torch.testing.assert_close(fast, slow.detach(), atol=1e-6, rtol=1e-6)
    assert bool((fast >= x).all()) and not torch.equal(fast, x)


def test_effect_fast_paths_match_their_autograd_paths() -> None:
    """The in-place (no autograd) code of each effect equals its differentiable code."""
    gen = torch.Generator().manual_seed(0)
    height = torch.rand(3, 1, 64, 64, generator=gen) * 0.5
    image = torch.rand(3, 3, 64, 64, generator=gen) * 255
    ctx = EffectContext()
    cases = {
        "shadows": lambda x: new_scene(x, torch.full((1, 3, 64, 64), 120.0)),
        "camera_noise": lambda x: image + x.mean() * 0,
        "gamma_white_balance": lambda x: image + x.mean() * 0,
    }
    for name, make in cases.items():
        effect = EFFECTS[name]
        fast = effect.apply(make(height), {}, torch.Generator().manual_seed(1), ctx)
        slow = effect.apply(make(height.requires_grad_()), {}, torch.Generator().manual_seed(1))
        height = height.detach()
        fast = fast.gain if name == "shadows" else fast
        slow = slow.gain if name == "shadows" else slow
        torch.testing.assert_close(fast, slow.detach(), atol=1e-3, rtol=1e-5)
    grad_in = image.clone().requires_grad_()
    torch.testing.assert_close(
        jpeg_approx(image, 85, (320, 240)), jpeg_approx(grad_in, 85, (320, 240)).detach()
    )


@needs_embree
def test_embree_height_field_matches_pybullet() -> None:
    meshes = [braille_mesh(c, BrailleSpec()) for c in ("Y", "#")]
    xs = np.linspace(-4.0, 4.0, 41)  # grid nodes through vertices and edges on purpose
    args = ([(m.vertices, m.faces) for m in meshes], xs, xs[::-1], 3.5, -1.0, 0.0)
    ours = raycast_heights(*args, backend="embree")
    reference = raycast_heights(*args, backend="pybullet")
    np.testing.assert_allclose(ours, reference, atol=1e-5)


@needs_embree
def test_embree_fast_path_matches_the_generic_ray_path() -> None:
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    renderer = MeshDepthRenderer.from_trimesh(mesh, GelSpec(size=16))
    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (6, 1, 1))
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down -z onto the sphere's top
    poses[:, :3, 3] = np.column_stack([rng.normal(0, 2, (6, 2)), np.full(6, 19.5)])
    fast = renderer.render_height(poses)
    reference = renderer.render_rays(poses)
    torch.testing.assert_close(fast, reference, atol=1e-4, rtol=0)
    assert float(fast.amax()) > 0.4  # pressed into the sphere


@pytest.mark.slow
@pytest.mark.parametrize("objects", [("037_scissors",), ("037_scissors", "042_adjustable_wrench")])
def test_corpus_is_the_same_built_in_worker_processes(tmp_path, objects) -> None:
    """Objects (or, for one object, groups of its trajectories) built in spawned workers give
    byte-identical shards and the same manifest."""
    from tactile_bench.data.ycb_slide import build_ycb_slide_standin

    kw = {"objects": objects, "progress": False, "n_pairs": 20}
    one = build_ycb_slide_standin(tmp_path / "one", workers=1, **kw)
    two = build_ycb_slide_standin(tmp_path / "two", workers=2, **kw)
    assert [s["sha256"] for s in one["shards"]] == [s["sha256"] for s in two["shards"]]
    # no timing in it either: the manifest's hash keys every stage downstream
    assert one == two


def test_jobs_are_split_so_every_worker_has_as_many_frames() -> None:
    from tactile_bench.data.ycb_slide import StandinConfig
    from tactile_bench.data.ycb_workers import ObjectJob, split_jobs

    def job(n_pairs: int) -> ObjectJob:
        config = StandinConfig(n_pairs=n_pairs, objects=("037_scissors",))
        chunks = -(-config.frames_per_trajectory // 64)
        todo = [(k, 0, chunks) for k in range(5)]
        return ObjectJob("x", 0, config, None, None, None, None, None, None, todo)

    # 5 trajectories of 160 frames (chunks of 64, 64, 32) over 2 workers: 384 and 416 frames
    assert [j.todo for j in split_jobs([job(800)], 2)] == [
        [(0, 0, 3), (1, 0, 3), (2, 0, 1)],
        [(2, 1, 3), (3, 0, 3), (4, 0, 3)],
    ]
    # one chunk a trajectory: split by trajectory
    assert [j.todo for j in split_jobs([job(20)], 2)] == [
        [(0, 0, 1), (1, 0, 1), (2, 0, 1)],
        [(3, 0, 1), (4, 0, 1)],
    ]
    assert [j.todo for j in split_jobs([job(20)] * 2, 2)] == [[(k, 0, 1) for k in range(5)]] * 2
    assert len(split_jobs([job(20)], 8)) == 5  # at most one chunk a job


def test_a_trajectory_built_in_pieces_is_the_one_built_whole(tmp_path) -> None:
    """Each chunk draws from its own generator, so splitting a trajectory over jobs (as the
    builder does to balance its workers) writes the same shard."""
    from tactile_bench.data.ycb_slide import StandinConfig
    from tactile_bench.data.ycb_workers import ObjectJob, build_object, write_shard
    from tactile_bench.sensor.background import sim_background
    from tactile_bench.sensor.surrogate import SurrogateDigit

    gel = GelSpec(size=16)
    config = StandinConfig(n_pairs=140, objects=("037_scissors",), n_trajectories=2)
    real = SurrogateDigit.from_profile("digit")
    bg = sim_background(16)
    whole = ObjectJob(
        "037_scissors", 0, config, gel, SimOptics(), bg, real, real.background(gel),
        tmp_path, [(1, 0, 2)],
    )  # fmt: skip
    assert config.frames_per_trajectory == 70
    n = build_object(whole).written[1]  # scissors drop frames that would collide
    assert n > 40
    reference = (tmp_path / "shards/037_scissors_1.npz").read_bytes()
    first = build_object(dataclasses.replace(whole, todo=[(1, 1, 2)]))  # the later chunk first
    second = build_object(dataclasses.replace(whole, todo=[(1, 0, 1)]))
    assert not first.written and not second.written
    pieces = {**first.pieces, **second.pieces}
    assert sorted(pieces) == [(1, 0, 1), (1, 1, 2)]
    assert write_shard(whole, 1, [pieces[p] for p in sorted(pieces)]) == n
    assert (tmp_path / "shards/037_scissors_1.npz").read_bytes() == reference


# ------------------------------------------------------------ parallel parts of one stream
def _state(generator: torch.Generator) -> torch.Tensor:
    return generator.get_state()


@pytest.mark.parametrize("profile", ["digit", "digit-b"])
def test_skip_random_replays_exactly_what_render_draws(bank, profile: str) -> None:
    from tactile_bench.sensor.surrogate import SurrogateDigit

    real, gel = SurrogateDigit.from_profile(profile), GelSpec(size=16)
    poses = classifier_protocol(CHARS).index(torch.arange(0, 300, 2))  # 150: a partial chunk
    for n in (5, len(poses)):
        rendered, skipped = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
        real.render(bank, poses.index(slice(0, n)), gel, rendered)
        real.skip_random(n, gel, skipped)
        assert torch.equal(_state(rendered), _state(skipped)), n
        sim_r, sim_s = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
        SimOptics().render(torch.zeros(n, 1, 16, 16), torch.zeros(3, 16, 16), sim_r)
        SimOptics().skip_random(n, gel, sim_s)
        assert torch.equal(_state(sim_r), _state(sim_s)), n


def test_every_stochastic_effect_declares_its_draws() -> None:
    from tactile_bench.effects.draws import replay_draws
    from tactile_bench.geometry.contacts import Poses

    n, hw, image_hw = 5, (24, 24), (12, 12)
    inputs = {
        "pose": Poses(
            torch.zeros(n), torch.zeros(n), torch.zeros(n), torch.zeros(n), torch.ones(n)
        ),
        "geometry": torch.rand(n, 1, *hw) - 0.5,
        "camera": torch.rand(n, 3, *image_hw) * 255,
    }
    for effect in EFFECTS.values():
        if not effect.stochastic:
            assert effect.draws(n, hw, image_hw) == [], effect.name
            continue
        applied, replayed = torch.Generator().manual_seed(6), torch.Generator().manual_seed(6)
        effect.apply(inputs[effect.acts_on], {}, applied, EffectContext(yaw_deg=torch.zeros(n)))
        replay_draws(effect.draws(n, hw, image_hw), replayed)
        assert torch.equal(_state(applied), _state(replayed)), effect.name


@pytest.mark.parametrize("chunk", [100, 256])  # cut on chunks, or on the surrogate's 128s
def test_threaded_braille_set_equals_the_sequential_one(bank, chunk: int) -> None:
    from tactile_bench.data.braille import render_braille_set
    from tactile_bench.sensor.surrogate import SurrogateDigit

    gel, real = GelSpec(size=16), SurrogateDigit.from_profile("digit")
    poses = classifier_protocol(CHARS).index(torch.arange(0, 1188, 3))  # 396 contacts
    bg = torch.full((3, 16, 16), 100, dtype=torch.uint8)

    def build(threads: int):
        gens = (torch.Generator().manual_seed(1), torch.Generator().manual_seed(2))
        s = render_braille_set(
            bank, poses, gel, SimOptics(), bg, real, bg, *gens, chunk=chunk, threads=threads
        )
        return s, gens

    (one, gens1), (three, gens3) = build(1), build(3)
    for name in ("depth", "sim", "real"):
        assert torch.equal(getattr(one, name), getattr(three, name)), name
    assert all(torch.equal(_state(a), _state(b)) for a, b in zip(gens1, gens3, strict=True))


def test_exposed_surface_is_the_same_every_time() -> None:
    """trimesh re-casts edge-grazing rays in random directions: seeded, so that builds in
    different processes (and reruns) slide over the same surface."""
    from tactile_bench.geometry.objects import object_parts
    from tactile_bench.geometry.trajectories import exposed_surface

    parts = object_parts("035_power_drill", 5)  # overlapping parts with grazing rays
    first = exposed_surface(parts).points
    for _ in range(2):
        assert np.array_equal(exposed_surface(parts).points, first)


def test_default_corpus_poses_are_proper_rotations() -> None:
    """The drill's 5th slide of the default 8000-pair corpus turns along the surface normal at
    frame 67; the gel frame there used to collapse (a zero axis: the renderer rejected it)."""
    from tactile_bench.geometry.objects import object_parts
    from tactile_bench.geometry.trajectories import exposed_surface, sliding_trajectories

    surface = exposed_surface(object_parts("035_power_drill", 5))  # object 5 of seed 0
    for traj in sliding_trajectories(surface, "035_power_drill", 5, 160, seed=5):
        for poses in (traj.poses, traj.measured):
            rot = poses[:, :3, :3]
            np.testing.assert_allclose(
                rot @ rot.transpose(0, 2, 1), np.tile(np.eye(3), (160, 1, 1)), atol=1e-6
            )


def test_a_failing_skip_stops_the_threaded_build_with_its_error(bank) -> None:
    """The parts after the first wait for their generators; a skip that raises must not
    leave them waiting."""
    from tactile_bench.data.braille import render_braille_set
    from tactile_bench.sensor.surrogate import SurrogateDigit

    class Broken(SurrogateDigit):
        def skip_random(self, n: int, gel: GelSpec, generator: torch.Generator) -> None:
            raise RuntimeError("skip failed")

    gel, real = GelSpec(size=16), Broken.from_profile("digit")
    poses = classifier_protocol(CHARS).index(torch.arange(0, 1188, 3))
    bg = torch.full((3, 16, 16), 100, dtype=torch.uint8)
    gens = (torch.Generator().manual_seed(1), torch.Generator().manual_seed(2))
    with pytest.raises(RuntimeError, match="skip failed"):
        render_braille_set(bank, poses, gel, SimOptics(), bg, real, bg, *gens, threads=2)
