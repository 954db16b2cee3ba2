"""The pairs' frame-to-frame noise: the part of the gap no candidate simulator can remove.

Away from its contact, a frame differs from the per-pixel median of many frames of the same
sensor only by what varies from frame to frame (read and shot noise, flicker): the
deterministic light and the camera's fixed effects cancel (``metrics.estimate_pixel_noise``,
with the pixels near any contact left out). That is measured for the real frames and for
the sim's alike (a noisy renderer, as TACTO's with its noise on). A no-contact frame that is
a single capture carries a frozen draw of the same noise into every candidate built on it;
how much, is bounded by the data (see ``frozen_variance``). A simulator that reproduced the
real sensor exactly would still leave the gap these noises make against each other; the
diagnosis subtracts it as a floor (``which``) instead of calling it unexplained.

Assumptions, stated because the floor rests on them: the noise is additive, independent from
frame to frame and from pixel to pixel (the floor is drawn as white Gaussian noise of the
measured variance), and the same near the contact as away from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.gapfit import PostDraw, Target, pair_gap
from tactile_bench.diagnose.scene import PairScene
from tactile_bench.metrics.noise import MIN_FRAMES, clipped_std, estimate_pixel_noise

#: pixels within this share of the image size of any contact are left out: a gel's spread,
#: a misregistered depth or a shadow reach past the depth's own contact
MARGIN_SHARE = 1 / 8
MIN_PIXELS = 64  # fewer contact-free pixels than this measure no frozen draw
MOSTLY_FREE = 0.75  # share of frames without a contact near a pixel, for its median


def contact_free(depth: torch.Tensor) -> torch.Tensor:
    """(N, 1, S, S) True where a pixel is at least the margin away from every contact."""
    margin = max(2, round(depth.shape[-1] * MARGIN_SHARE))
    near = F.max_pool2d((depth > 0).float(), 2 * margin + 1, stride=1, padding=margin)
    return near == 0


def frame_variance(frames: torch.Tensor, free: torch.Tensor) -> torch.Tensor:
    """(3,) noise variance per channel of ``frames`` (N, 3, S, S), measured frame to frame
    where no contact is near (``free``, (N, 1, S, S)); 0 with too few frames or pixels."""
    sigma = estimate_pixel_noise(frames, free)
    return frames.new_zeros(frames.shape[1]).float() if sigma is None else sigma.square()


def frozen_variance(
    frame: torch.Tensor, frames: torch.Tensor, free: torch.Tensor, variance: torch.Tensor
) -> torch.Tensor:
    """(3,) the noise a no-contact ``frame`` (3, S, S) carries frozen in it, next to
    ``frames`` of the same sensor with per-frame noise ``variance``.

    Its deviation from their per-pixel median, where most frames (``MOSTLY_FREE``) have no
    contact near, less the median's own noise (pi/2 variance / N for a median of N draws),
    at most ``variance`` (one capture's worth): a frame of another unit or an average of
    many comes out lower, never higher than one capture.
    """
    mostly = free.float().mean(dim=0)[0] >= MOSTLY_FREE  # (S, S)
    if len(frames) < MIN_FRAMES or int(mostly.sum()) < MIN_PIXELS:
        return torch.zeros_like(variance)
    deviation = frame.float() - frames.float().median(dim=0).values
    own = clipped_std(deviation[:, mostly]).square() - math.pi / 2 * variance / len(frames)
    return torch.minimum(own.clamp(min=0.0), variance)


@dataclass
class FrameNoise:
    """Noise variances per channel (grey level^2) estimated from the pairs themselves."""

    sim: torch.Tensor  # each sim frame's own draw
    real: torch.Tensor  # each real frame's own draw
    sim_background: torch.Tensor  # frozen in the sim's no-contact frame
    measured_background: torch.Tensor  # frozen in the measured no-contact frame

    @property
    def candidate(self) -> torch.Tensor:
        """(3,) the noise a candidate built on the sim and the measured frame carries."""
        return self.sim + self.sim_background + self.measured_background

    def floor(self, clean: torch.Tensor, seed: int = 0) -> torch.Tensor:
        """Per-pair gap (N,) between two noisy copies of ``clean`` (N, 3, S, S): the
        candidate's noise on one, a real frame's on the other (white, Gaussian)."""
        if not bool((self.candidate + self.real).gt(0).any()):
            return clean.new_zeros(len(clean))
        gen = torch.Generator().manual_seed(seed)
        draw = torch.randn((2, *clean.shape), generator=gen).to(clean.device)
        model = clean + draw[0] * self.candidate.sqrt()[:, None, None]
        real = clean + draw[1] * self.real.sqrt()[:, None, None]
        return pair_gap([model], Target.of(real))

    def topped_up(self, seed: int = 0) -> PostDraw:
        """A draw's frame-to-frame noise brought back up to the sim's measured level.

        An effect that re-renders or smooths the contact (a fitted response, a blur) also
        removes the sim's own noise, and against a less noisy camera that lowers the gap
        whatever the effect is. Scored with the noise put back (white, Gaussian, per channel,
        the same draw for every candidate), a candidate keeps only what it changes in the
        image formation. A draw too small to measure is left as it is.
        """

        def post(images: torch.Tensor, scene: PairScene, draw: int) -> torch.Tensor:
            have = estimate_pixel_noise(images, contact_free(scene.depth))
            if have is None:
                return images
            extra = (self.sim - have.square()).clamp(min=0.0).sqrt()
            gen = torch.Generator().manual_seed(seed + 104_729 * (draw + 1))
            noise = torch.randn(images.shape, generator=gen).to(images.device)
            return images + noise * extra[:, None, None]

        return post

    def to_dict(self) -> dict[str, list[float]]:
        """Each source's standard deviation per channel, grey levels."""
        return {
            k: [round(float(s), 3) for s in getattr(self, k).sqrt()]
            for k in ("sim", "real", "sim_background", "measured_background")
        }


def frame_noise(
    depth: torch.Tensor,
    sim: torch.Tensor,
    real: torch.Tensor,
    background: torch.Tensor,
    sim_background: torch.Tensor | None,
) -> FrameNoise:
    """The pairs' noise (see the module docstring). ``sim_background`` None: the sim was
    composited onto ``background``, whose frozen draw the real side already counts."""
    free = contact_free(depth)
    sim_var, real_var = frame_variance(sim, free), frame_variance(real, free)
    sim_frozen = (
        torch.zeros_like(sim_var)
        if sim_background is None
        else frozen_variance(sim_background, sim, free, sim_var)
    )
    return FrameNoise(
        sim_var, real_var, sim_frozen, frozen_variance(background, real, free, real_var)
    )
