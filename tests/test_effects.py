"""Contract tests for every registered effect: identity at neutral, seeded, validated, batched,
differentiable where declared; plus the JPEG approximation against a real encoder."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from tactile_bench.effects import EFFECT_ORDER, EFFECTS, EffectContext, OpticalScene, get_effect
from tactile_bench.effects.base import surface_gradient
from tactile_bench.effects.camera import jpeg_approx
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


def _input(stage: str, n: int = 3):
    if stage == "pose":
        return Poses(
            labels=torch.arange(n),
            x_mm=torch.linspace(-1, 1, n),
            y_mm=torch.zeros(n),
            yaw_deg=torch.linspace(-20, 20, n),
            press_mm=torch.full((n,), 0.5),
        )
    if stage == "geometry":
        return _height(n)
    if stage == "optics":
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
    assert {e.stage for e in EFFECTS.values()} == {"pose", "geometry", "optics", "camera"}
    for name, effect in EFFECTS.items():
        assert effect.name == name and effect.description and effect.params
        for p in effect.params:
            assert p.unit and p.source and p.low <= p.default <= p.high
    with pytest.raises(TactileBenchError, match="unknown effect 'nope'.*elastic_spread"):
        get_effect("nope")


@pytest.mark.parametrize("name", ALL)
def test_changes_when_on_and_identity_at_neutral(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.stage)
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
    x = _input(effect.stage)
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


@pytest.mark.parametrize("name", [n for n in ALL if not EFFECTS[n].stochastic])
def test_batched_equals_per_image(name: str) -> None:
    effect = get_effect(name)
    x = _input(effect.stage, n=3)
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
    x = _input(effect.stage)
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
