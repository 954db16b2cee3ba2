"""The ``lighting_aug`` translator: the paper's "Sim + data aug." baseline.

Higuera et al. (2023) train their "Sim + data aug." classifier on simulated images whose
lighting is randomised, so it sees many plausible sensors instead of TACTO's one ideal one.
Two modes, both adding only a contact's colour change to the caller's background:

- ``physical`` (default): every image gets its own lights inside the sim optics
  (``SimOptics.shade_change_lit``). Drawn per image and per light: the direction (azimuth
  jitter around TACTO's 30/150/270 deg), the elevation (circle radius and distance behind
  the gel), the intensity, and a colour near the light's nominal channel (some cross-talk
  into the others). The pressed gel and the flat gel are shaded under the same lights and
  subtracted, so only the contact's change varies; TACTO's other steps (``diff_scale``,
  low-pass, clamp) follow. There is no ambient draw: ambient light is the same on the
  pressed and the flat gel, so it cancels in that difference, and the background stays the
  caller's.
- ``image``: a kornia photometric pipeline (colour jitter, gamma, colour temperature, light
  gradients, blur). Its draw is applied to the composited sim image and, with the very same
  parameters, to the background alone; the contact's change is their difference, so the
  recolouring of the background does not leak into the foreground.

``translate(depth, background)`` returns, in both modes, ``background`` + that randomised
contact change + camera noise, clamped to 0..255: the background is never recoloured,
because classifiers take foregrounds against the unaugmented background.
``translate_foreground`` is the same on the sim background, as a foreground.

Camera noise: Gaussian, per colour channel. Unfitted, SimOptics' std 7 (0..255) as TACTO;
``fit_pairs`` replaces it by the std measured on real foregrounds
(``metrics.noise.estimate_pixel_noise``, as the diffusion translator does). That estimate
is all this translator fits: no network, no Trainer, ``max_steps`` ignored.

Why these default ranges: moderate variations of one sensor design, not other sensors.
TACTO's DIGIT (``tacto/config_digit.yml``) puts its lights on a 20 mm circle 17 mm behind
the gel (elevation ~40 deg); +-10 deg of azimuth, 17..23 mm of radius and 14..20 mm of
distance (elevation ~31..50 deg) are the mounting and scattering differences between units.
Intensity 0.75..1.25 covers LED brightness tolerance and coating reflectance; cross-talk up
to 0.15 is a camera's colour filters overlapping the LEDs' spectra.

Randomness: everything is drawn from the caller's generator (kornia draws from torch's
global RNG, so ``image`` mode runs it inside a forked RNG seeded from that generator): same
generator seed, same images, global RNG state intact.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import kornia.augmentation as K
import torch
from lightning.pytorch.loggers import Logger
from pydantic import AfterValidator, Field

from tactile_bench.errors import TactileBenchError
from tactile_bench.metrics.noise import MIN_FRAMES, estimate_pixel_noise
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.translators.base import image_to_foreground
from tactile_bench.translators.sim import SimConfig, SimTranslator


def _ordered(bounds: tuple[float, float]) -> tuple[float, float]:
    if bounds[0] > bounds[1]:
        raise ValueError(f"a (low, high) range needs low <= high, got {tuple(bounds)}")
    return bounds


Range = Annotated[tuple[float, float], AfterValidator(_ordered)]
Positive = Annotated[float, Field(gt=0)]
PositiveRange = Annotated[tuple[Positive, Positive], AfterValidator(_ordered)]


class LightingAugConfig(SimConfig):
    """Which randomisation, and its ranges (see the module docstring for why these)."""

    max_steps: int = Field(default=0, description="ignored: fitting only measures camera noise")
    mode: Literal["physical", "image"] = Field(
        default="physical",
        description="physical: random lights inside the sim optics; image: a kornia "
        "photometric draw on image and background alike",
    )
    camera_noise: bool = Field(
        default=True,
        description="add camera noise: the std fitted on real foregrounds, else SimOptics' 7",
    )
    # physical mode
    light_angle_jitter_deg: float = Field(
        default=10.0, ge=0, le=60, description="each light's azimuth moves by up to +- this"
    )
    light_radius_mm: PositiveRange = Field(
        default=(17.0, 23.0), description="radius of each light's circle, mm (TACTO: 20)"
    )
    light_distance_mm: PositiveRange = Field(
        default=(14.0, 20.0),
        description="each light's distance behind the gel, mm (TACTO: 17); sets its elevation",
    )
    light_intensity: PositiveRange = Field(
        default=(0.75, 1.25), description="each light's intensity relative to TACTO's"
    )
    light_crosstalk: float = Field(
        default=0.15,
        ge=0,
        le=1,
        description="largest share of a light seen in each other colour channel",
    )
    # image mode (kornia)
    brightness: float = Field(default=0.2, ge=0, le=1, description="ColorJitter brightness")
    contrast: float = Field(default=0.2, ge=0, description="ColorJitter contrast")
    saturation: float = Field(default=0.2, ge=0, description="ColorJitter saturation")
    hue: float = Field(default=0.03, ge=0, le=0.5, description="ColorJitter hue")
    gamma: PositiveRange = Field(default=(0.8, 1.25), description="range of the random gamma")
    planckian_p: float = Field(
        default=0.5, ge=0, le=1, description="probability of a black-body colour temperature"
    )
    linear_illumination_gain: Range = Field(
        default=(0.01, 0.15), description="gain range of the linear and corner light gradients"
    )
    illumination_p: float = Field(
        default=0.5, ge=0, le=1, description="probability of each light gradient"
    )
    blur_sigma: PositiveRange = Field(
        default=(0.1, 1.0), description="sigma range of the Gaussian blur"
    )
    blur_p: float = Field(default=0.3, ge=0, le=1, description="probability of that blur")


def build_augmentation(cfg: LightingAugConfig) -> K.AugmentationSequential:
    """The ``image`` mode's kornia pipeline, taking (image, background): one draw for both.

    Two ``input`` data keys make kornia apply the same sampled parameters to both inputs.
    No noise step: a replayed noise draw would cancel in the difference; the camera noise
    is added afterwards in both modes.
    """
    return K.AugmentationSequential(
        K.ColorJitter(cfg.brightness, cfg.contrast, cfg.saturation, cfg.hue, p=1.0),
        K.RandomGamma(gamma=cfg.gamma, p=1.0),
        K.RandomPlanckianJitter(mode="blackbody", p=cfg.planckian_p),
        K.RandomLinearIllumination(gain=cfg.linear_illumination_gain, p=cfg.illumination_p),
        K.RandomLinearCornerIllumination(gain=cfg.linear_illumination_gain, p=cfg.illumination_p),
        K.RandomGaussianBlur((5, 5), cfg.blur_sigma, p=cfg.blur_p),
        data_keys=["input", "input"],
    )


def _uniform(
    shape: tuple[int, ...], bounds: tuple[float, float], generator: torch.Generator
) -> torch.Tensor:
    return torch.rand(shape, generator=generator).mul_(bounds[1] - bounds[0]).add_(bounds[0])


class LightingAugTranslator(SimTranslator):
    """Depth -> sim image under randomised lighting. Fits only the camera noise, no network
    (``trainable`` stays False: there is nothing for a Trainer to train)."""

    name = "lighting_aug"
    Config = LightingAugConfig
    trainable = False

    def __init__(self, config: LightingAugConfig | dict[str, Any] | None = None) -> None:
        super().__init__(config)
        # camera noise measured by ``fit_pairs``: per-channel std in foreground units
        self.register_buffer("camera_noise_std", torch.zeros(3))
        self.register_buffer("camera_noise_fitted", torch.zeros((), dtype=torch.bool))

    @property
    def pixel_noise_std(self) -> torch.Tensor:
        """Per-channel camera noise std (3,) in foreground units (zeros when switched off)."""
        if not self.config.camera_noise:
            return torch.zeros(3)
        if bool(self.camera_noise_fitted):
            return self.camera_noise_std.detach().cpu().clone()
        return torch.full((3,), self.optics.noise_std / 255.0)

    def fit_pairs(
        self,
        depth: torch.Tensor,
        foreground: torch.Tensor,
        out_dir: Path,
        trainer: dict[str, Any] | None = None,
        loggers: list[Logger] | None = None,
    ) -> None:
        """Measure the real camera's per-channel noise on ``foreground`` (N, 3, S, S).

        The one thing this translator fits; no Trainer runs (``depth``, ``out_dir``,
        ``trainer`` and ``loggers`` are unused) and it returns None.
        """
        if foreground.dim() != 4 or foreground.shape[1] != 3:
            raise TactileBenchError(
                f"translator {self.name!r}: real foregrounds must be (N, 3, S, S), "
                f"got {tuple(foreground.shape)}"
            )
        estimate = estimate_pixel_noise(foreground)
        if estimate is None:
            raise TactileBenchError(
                f"translator {self.name!r}: measuring the camera noise needs at least "
                f"{MIN_FRAMES} real foregrounds, got {len(foreground)}"
            )
        self.camera_noise_std.copy_(estimate)
        self.camera_noise_fitted.fill_(True)

    def fit_diagnostics(self) -> dict[str, Any]:
        return {"camera_noise_std": self.pixel_noise_std.tolist()}

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any) -> None:
        # checkpoints from before the noise fit: unfitted, and their kornia state is unused
        for key in [k for k in state_dict if k.startswith(prefix + "augment.")]:
            del state_dict[key]
        for name in ("camera_noise_std", "camera_noise_fitted"):
            state_dict.setdefault(prefix + name, getattr(self, name).clone())
        super()._load_from_state_dict(state_dict, prefix, *args)

    def draw_lights(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` random lightings: positions (n, light, xyz) in mm and colours (n, light,
        channel) on the 0..255 scale, as ``SimOptics.shade_change_lit`` takes them."""
        cfg, optics = self.config, self.optics
        jitter = (torch.rand(n, 3, generator=generator) * 2 - 1) * cfg.light_angle_jitter_deg
        angle = torch.deg2rad(torch.tensor(optics.light_angles_deg) + jitter)
        radius = _uniform((n, 3), cfg.light_radius_mm, generator)
        distance = _uniform((n, 3), cfg.light_distance_mm, generator)
        positions = torch.stack([radius * angle.cos(), radius * angle.sin(), distance], -1)
        intensity = _uniform((n, 3, 1), cfg.light_intensity, generator) * optics.intensity
        crosstalk = torch.rand(n, 3, 3, generator=generator) * cfg.light_crosstalk
        eye = torch.eye(3)
        colours = (eye + (1 - eye) * crosstalk) * intensity
        return positions, colours

    def _augmented_change(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        gel: GelSpec,
        generator: torch.Generator,
    ) -> torch.Tensor:
        """``image`` mode: aug(sim image) - aug(background) with one draw, 0..255 scale."""
        background = background.expand(len(depth), *background.shape[-3:]).contiguous()
        clean = (background + self.optics.contact_change(depth, gel)).clamp_(0, 255)
        seed = int(torch.randint(0, 2**62, (1,), generator=generator))
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            image, bg = build_augmentation(self.config)(clean / 255.0, background / 255.0)
        return (image - bg).mul_(255.0)

    def _image(
        self, depth: torch.Tensor, background: torch.Tensor, generator: torch.Generator | None
    ) -> torch.Tensor:
        """Background + randomised contact change + camera noise, clamped: (N, 3, S, S)."""
        generator = self._generator(generator)
        device = depth.device
        depth, background = depth.float(), background.float().to(device)
        gel = GelSpec(size=depth.shape[-1])
        if self.config.mode == "physical":
            # drawn on the CPU (the same lights on every device), shaded on the depth's
            lights, colours = self.draw_lights(len(depth), generator)
            change = self.optics.contact_change(depth, gel, lights.to(device), colours.to(device))
        else:
            change = self._augmented_change(depth, background, gel, generator)
        image = change.add_(background)
        std = self.pixel_noise_std.to(device)
        if bool(self.pixel_noise_std.any()):
            noise = torch.randn(image.shape, generator=generator).to(device)
            image.add_(noise.mul_(std.view(1, 3, 1, 1) * 255.0))
        return image.clamp_(0, 255)

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        background = sim_background(depth.shape[-1])
        return image_to_foreground(self._image(depth, background, generator), background)

    @torch.no_grad()
    def translate(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        return self._image(depth, background, generator)
