"""Contract tests for every registered effect: identity at neutral, seeded, validated, batched,
differentiable where declared; plus the JPEG approximation against a real encoder."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from tactile_bench.effects import (
    EFFECT_ORDER,
    EFFECTS,
    IMAGE_FORMATION,
    EffectContext,
    OpticalScene,
    get_effect,
)
from tactile_bench.effects.camera import jpeg_approx
from tactile_bench.effects.kernels import surface_gradient
from tactile_bench.effects.optics import fitted_response_image, new_scene
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.contacts import Poses
from tactile_bench.sensor.background import digit_background, sim_background

S = 32
CTX = EffectContext()


def _height(n: int = 3, size: int = 48) -> torch.Tensor:
    """Signed height (n, 1, size, size): a 1 mm dome per image, pressed 0.3-0.7 mm in."""
    t = (torch.arange(size) + 0.5) / size * 2 - 1
    yy, xx = torch.meshgrid(t * 12, t * 9, indexing="ij")
    out = []
    for i in range(n):
        r2 = (xx - 1.5 * i) ** 2 + (yy + i) ** 2
        dome = (1.0 - r2 / 1.5**2).clamp(min=0) ** 0.5
        out.append(dome - 1.0 + 0.3 + 0.2 * i)
    return torch.stack(out)[:, None].float()


def _input(acts_on: str, n: int = 3):
    if acts_on == "pose":
        return Poses(
            labels=torch.arange(n),
            x_mm=torch.linspace(-1, 1, n),
            y_mm=torch.zeros(n),
            yaw_deg=torch.linspace(-20, 20, n),
            press_mm=torch.full((n,), 0.5),
        )
    if acts_on == "geometry":
        return _height(n)
    if acts_on == "optics":
        surface = torch.nn.functional.adaptive_avg_pool2d(_height(n).clamp(min=0), S)
        gx, gy = surface_gradient(surface, CTX)
        delta = fitted_response_image(gx[:, 0], gy[:, 0], (surface[:, 0] > 0).float())
        return new_scene(surface, digit_background(S), delta)
    # camera effects see the model-size image (64: the defocus PSF is under a pixel at 32)
    bg = sim_background(64)[None].repeat(n, 1, 1, 1)
    spot = torch.zeros(n, 3, 64, 64)
    colour = torch.tensor([60.0, -40.0, 30.0])[:, None, None]
    for i in range(n):
        spot[i, :, 20 + i : 28 + i, 16 : 24 + 2 * i] = colour
    return bg + spot


def _as_tensor(out) -> torch.Tensor:
    if isinstance(out, Poses):
        return torch.stack([out.x_mm, out.y_mm, out.yaw_deg, out.press_mm])
    if isinstance(out, OpticalScene):
        return out.composite()
    return out


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


ALL = list(EFFECT_ORDER)


def test_registry_is_explicit_and_complete() -> None:
    assert len(EFFECTS) >= 15
    assert {e.acts_on for e in EFFECTS.values()} == set(IMAGE_FORMATION)
    for name, effect in EFFECTS.items():
        assert effect.name == name and effect.description and effect.params
        for p in effect.params:
            assert p.unit and p.source and p.low <= p.default <= p.high
    with pytest.raises(TactileBenchError, match="unknown effect 'nope'.*elastic_spread"):
        get_effect("nope")


@pytest.mark.parametrize("name", ALL)
def test_changes_when_on_and_identity_at_neutral(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.acts_on)
    ref = _as_tensor(x)
    on = _as_tensor(effect.apply(x, None, _gen(), CTX))
    assert on.shape == ref.shape
    assert not torch.allclose(on, ref, atol=1e-4), f"{name} changed nothing at its defaults"
    off = effect.apply(x, effect.neutral_params(), _gen(), CTX)
    assert off is x
    # neutral values that are being fitted (requires_grad) go through the maths: still ~identity
    neutral = effect.neutral_params().items()
    fitted = {k: torch.tensor(float(v), requires_grad=True) for k, v in neutral}
    near = _as_tensor(effect.apply(x, fitted, _gen(), CTX)).detach()
    assert torch.allclose(near, ref, atol=1e-3), f"{name} not the identity at neutral"


@pytest.mark.parametrize("name", ALL)
def test_seeded_determinism(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.acts_on)
    a = _as_tensor(effect.apply(x, None, _gen(1), CTX))
    b = _as_tensor(effect.apply(x, None, _gen(1), CTX))
    assert torch.equal(a, b)
    if effect.stochastic:
        c = _as_tensor(effect.apply(x, None, _gen(2), CTX))
        assert not torch.equal(a, c), f"{name} ignores its generator"
        # a no-contact reference frame draws no per-frame randomness
        quiet = EffectContext(stochastic=False)
        d = _as_tensor(effect.apply(x, None, _gen(1), quiet))
        e = _as_tensor(effect.apply(x, None, _gen(2), quiet))
        assert torch.equal(d, e)


@pytest.mark.parametrize("name", ALL)
def test_out_of_range_and_unknown_params(name: str) -> None:
    effect = get_effect(name)
    p = effect.params[0]
    with pytest.raises(TactileBenchError, match=f"{name}.*{p.name}"):
        effect.validate({p.name: p.high + 10 * (abs(p.high) + 1)})
    with pytest.raises(TactileBenchError, match=f"{name}.*{p.name}"):
        effect.validate({p.name: p.low - 10 * (abs(p.low) + 1)})
    with pytest.raises(TactileBenchError, match=f"{name}.*bogus"):
        effect.validate({"bogus": 1.0})
    with pytest.raises(TactileBenchError, match=f"{name}.*{p.name}"):
        effect.validate({p.name: "high"})


@pytest.mark.parametrize("name", ALL)
def test_range_bounds_are_valid_values_in_any_precision(name: str) -> None:
    effect = get_effect(name)
    for p in effect.params:
        for bound in (p.low, p.high):
            for value in (bound, torch.tensor(bound), torch.tensor([bound, bound])):
                assert effect.validate({p.name: value})[p.name] is value


@pytest.mark.parametrize("name", [n for n in ALL if not EFFECTS[n].stochastic])
def test_batched_equals_per_image(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.acts_on, n=3)
    batched = _as_tensor(effect.apply(x, None, _gen(), CTX))
    singles = []
    for i in range(3):
        if isinstance(x, OpticalScene):
            xi = new_scene(x.height[i : i + 1], x.background, x.delta[i : i + 1])
        else:
            xi = x[i : i + 1]
        singles.append(_as_tensor(effect.apply(xi, None, _gen(), CTX)))
    assert torch.allclose(batched, torch.cat(singles), atol=1e-3)


@pytest.mark.parametrize("name", [n for n in ALL if EFFECTS[n].differentiable])
def test_gradients_flow_to_declared_params(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.acts_on)
    params = {k: torch.tensor(float(v), requires_grad=True) for k, v in effect.defaults().items()}
    out = _as_tensor(effect.apply(x, params, _gen(), CTX))
    weights = torch.linspace(0.5, 1.5, out.numel()).reshape(out.shape)
    (out * weights).sum().backward()
    for k in effect.differentiable:
        g = params[k].grad
        assert g is not None and torch.isfinite(g), f"{name}.{k}: no gradient"
        assert float(g.abs()) > 0, f"{name}.{k}: zero gradient"


def test_jpeg_approximation_close_to_a_real_encoder() -> None:
    """The DCT approximation at the native frame size vs libjpeg through PIL, quality 85."""
    from PIL import Image

    img = digit_background((320, 240))
    yy, xx = torch.meshgrid(torch.arange(320.0), torch.arange(240.0), indexing="ij")
    img = (img + 25 * torch.exp(-((xx - 120) ** 2 + (yy - 160) ** 2) / 200)).clamp(0, 255)
    img = img.round()
    ours = jpeg_approx(img[None], 85, (320, 240))[0]
    buf = io.BytesIO()
    pil = Image.fromarray(img.permute(1, 2, 0).byte().numpy())
    pil.save(buf, format="JPEG", quality=85, subsampling=2)
    real = torch.from_numpy(np.asarray(Image.open(buf)).astype(np.float32)).permute(2, 0, 1)
    err_real = (real - img).abs().mean()
    err_ours = (ours - img).abs().mean()
    assert float((ours - real).abs().mean()) < 1.5
    assert 0.3 < float(err_ours / err_real) < 3.0


# --------------------------------------------------------------------------- fast paths
# The effects run as matrix products, per-image kernels and in-cache sub-batches. These are
# the direct, slow definitions they replaced (conv2d blur, N grid_sample shifts, JPEG via
# interpolate + 8 x 8 block DCT, masks by torch.where): the fast paths must match them.
def _ref_blur(x: torch.Tensor, sx: float, sy: float) -> torch.Tensor:
    import math

    from tactile_bench.effects.kernels import conv1d_slices, gaussian_kernel1d

    if sx > 4 and sy > 4:  # the wide path: 2x area down, blur, bilinear up
        small = torch.nn.functional.avg_pool2d(x, 2)
        small = _ref_blur(small, (sx**2 - 1 / 12) ** 0.5 / 2, (sy**2 - 1 / 12) ** 0.5 / 2)
        return torch.nn.functional.interpolate(small, size=x.shape[-2:], mode="bilinear")
    kx = gaussian_kernel1d(torch.tensor(sx), min(64, math.ceil(3 * sx), x.shape[-1] - 1))
    ky = gaussian_kernel1d(torch.tensor(sy), min(64, math.ceil(3 * sy), x.shape[-2] - 1))
    return conv1d_slices(conv1d_slices(x, kx, -1), ky, -2)


@pytest.mark.parametrize(("sx", "sy"), [(0.43, 0.32), (1.6, 1.2), (6.4, 4.8), (17.8, 13.3)])
def test_matrix_blur_matches_convolution(sx: float, sy: float) -> None:
    from tactile_bench.effects.kernels import gaussian_blur

    x = torch.randn(3, 2, 128, 96, generator=_gen())
    ours = gaussian_blur(x, torch.tensor(sx), torch.tensor(sy))
    assert torch.allclose(ours, _ref_blur(x, sx, sy), atol=1e-5)
    # differentiable in sigma through the matrices
    s = torch.tensor(sx, requires_grad=True)
    gaussian_blur(x, s, torch.tensor(sy)).square().sum().backward()
    assert s.grad is not None and torch.isfinite(s.grad)


@pytest.mark.parametrize("smear_mm", [0.1, 1.2])
def test_shear_smear_matches_shifted_samples(smear_mm: float) -> None:
    from tactile_bench.effects.kernels import pixel_grid

    def shift_mm(x: torch.Tensor, dx_mm: torch.Tensor, dy_mm: torch.Tensor, ctx) -> torch.Tensor:  # type: ignore[no-untyped-def]
        """``x`` sampled at (p + d), d in mm: the content moves by -d."""
        n, _, h, w = x.shape
        uu, vv = pixel_grid(h, w)
        du = (2.0 * dx_mm / ctx.width_mm).reshape(-1, 1, 1)
        dv = (2.0 * dy_mm / ctx.height_mm).reshape(-1, 1, 1)
        grid = torch.stack([(uu + du).expand(n, h, w), (vv + dv).expand(n, h, w)], dim=-1)
        return torch.nn.functional.grid_sample(
            x, grid, mode="bilinear", padding_mode="border", align_corners=False
        )

    effect, x = get_effect("shear_smear"), _height(4, 64)
    ours = effect.apply(x, {"smear_mm": smear_mm}, _gen(3), CTX)
    theta = torch.rand(4, generator=_gen(3)) * 2 * np.pi
    steps = [smear_mm * k / (effect.steps - 1) for k in range(effect.steps)]
    ref = sum(shift_mm(x, t * torch.cos(theta), t * torch.sin(theta), CTX) for t in steps)
    assert torch.allclose(ours, ref / effect.steps, atol=1e-5)


def test_elastic_spread_matches_masked_pyramid() -> None:
    from tactile_bench.effects.kernels import gaussian_blur

    x = _height(3, 96)
    ours = get_effect("elastic_spread").apply(x, None, None, CTX)
    pen = x.clamp(min=0)
    core = pen > 0.4 * pen.amax(dim=(2, 3), keepdim=True)
    z, level, (dx, dy) = pen, 0.9, CTX.mm_per_px(x)
    while level / min(dx, dy) >= 1:
        z = torch.where(
            core, pen, gaussian_blur(z, torch.tensor(level / dx), torch.tensor(level / dy))
        )
        level /= 2
    assert torch.allclose(ours, torch.where(z > 0, torch.maximum(z, x), x), atol=1e-6)


def _ref_jpeg(x: torch.Tensor, quality: float, hw: tuple[int, int]) -> torch.Tensor:
    from tactile_bench.effects.camera import dct_matrix, quant_tables

    f = torch.nn.functional
    d2 = torch.kron(dct_matrix(), dct_matrix())

    def blocks(plane: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
        n, h, w = plane.shape
        b = plane.reshape(n, h // 8, 8, w // 8, 8).permute(0, 1, 3, 2, 4).reshape(-1, 64)
        coef = torch.round((b @ d2.T) / table.reshape(64)) * table.reshape(64)
        b = (coef @ d2).reshape(n, h // 8, w // 8, 8, 8)
        return b.permute(0, 1, 3, 2, 4).reshape(n, h, w)

    n, _, s, _ = x.shape
    (hh, ww), (q_l, q_c) = hw, quant_tables(quality)
    r, g, b = x[:, 0], x[:, 1], x[:, 2]
    lum = 0.299 * r + 0.587 * g + 0.114 * b - 128
    cb = -0.168736 * r - 0.331264 * g + 0.5 * b
    cr = 0.5 * r - 0.418688 * g - 0.081312 * b
    lum = f.interpolate(lum[:, None], size=(hh, ww), mode="bilinear")[:, 0]
    ch = f.interpolate(torch.stack([cb, cr], 1), size=(hh // 2, ww // 2), mode="bilinear")
    lum = f.adaptive_avg_pool2d(blocks(lum, q_l)[:, None], s)[:, 0] + 128
    ch = blocks(ch.reshape(2 * n, hh // 2, ww // 2), q_c).reshape(n, 2, hh // 2, ww // 2)
    cb, cr = f.adaptive_avg_pool2d(ch, s).unbind(1)
    rgb = torch.stack([lum + 1.402 * cr, lum - 0.344136 * cb - 0.714136 * cr, lum + 1.772 * cb], 1)
    return rgb.clamp(0, 255)


@pytest.mark.parametrize(("quality", "size"), [(85, 64), (40, 64), (95, 32)])
def test_jpeg_matrices_match_block_dct(quality: float, size: int) -> None:
    """Same maths in another order: a coefficient within float rounding of a .5 step may round
    the other way (~1e-5 of them), moving a few output pixels by < 2 DN."""
    x = _input("camera", 6)
    x = torch.nn.functional.adaptive_avg_pool2d(
        x + 9 * torch.randn(x.shape, generator=_gen()), size
    )
    d = (jpeg_approx(x, quality, (320, 240)) - _ref_jpeg(x, quality, (320, 240))).abs()
    assert float(d.mean()) < 1e-3 and float(d.max()) < 2.0
    assert float((d > 1e-3).float().mean()) < 1e-3


def test_jpeg_batch_layout_keeps_images_apart() -> None:
    """The codec works with the batch between rows and columns: each image must still be
    coded on its own (same as alone, and as the straight-through gradient path)."""
    x = torch.rand(5, 3, 64, 64, generator=_gen()) * 255
    batch = jpeg_approx(x, 85, (320, 240))
    alone = torch.cat([jpeg_approx(x[i : i + 1], 85, (320, 240)) for i in range(5)])
    torch.testing.assert_close(batch, alone, atol=1e-3, rtol=0)
    grad = jpeg_approx(x.clone().requires_grad_(), 85, (320, 240))
    torch.testing.assert_close(batch, grad.detach(), atol=1e-3, rtol=0)
    assert batch.is_contiguous() and batch.shape == x.shape
