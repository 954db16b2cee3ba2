"""The pairs' frame-to-frame noise: the part of the gap no candidate simulator can remove.

Away from its contact, a frame differs from the next frame of the same sensor only by what
varies from frame to frame (read and shot noise, flicker): the deterministic light and the
camera's fixed effects cancel in the difference. Its mean square over those pixels is twice
the frame's noise variance, for the real frames and for the sim's alike (a noisy renderer,
as TACTO's with its noise on). A no-contact frame that is a single capture carries a frozen
draw of the same noise into every candidate built on it; how much, is bounded by the data
(see ``FrameNoise``). A simulator that reproduced the real sensor exactly would still leave
the gap these noises make against each other; the diagnosis subtracts it as a floor
(``which._result``) instead of calling it unexplained.

Assumptions, stated because the floor rests on them: the noise is additive, independent from
frame to frame and from pixel to pixel (the floor is drawn as white Gaussian noise of the
measured variance), and the same near the contact as away from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from tactile_bench.diagnose.gapfit import Target, pair_gap

#: pixels within this share of the image size of any contact are left out: a gel's spread,
#: a misregistered depth or a shadow reach past the depth's own contact
MARGIN_SHARE = 1 / 8
MIN_PIXELS = 64  # a pair of frames with fewer contact-free pixels in common is skipped
TRIM = 4.0  # differences beyond this many robust standard deviations are not noise


def contact_free(depth: torch.Tensor) -> torch.Tensor:
    """(N, 1, S, S) True where a pixel is at least the margin away from every contact."""
    margin = max(2, round(depth.shape[-1] * MARGIN_SHARE))
    near = F.max_pool2d((depth > 0).float(), 2 * margin + 1, stride=1, padding=margin)
    return near == 0


def _mean_square(diff: torch.Tensor) -> torch.Tensor:
    """(3,) trimmed mean square of per-channel differences (C, M): a sparse change that is
    not noise (a drifting speck, a reflection) must not pass for it."""
    scale = 1.4826 * diff.abs().median(dim=1).values  # the MAD of a zero-mean Gaussian
    keep = diff.abs() <= (TRIM * scale).clamp(min=1.0)[:, None]
    return (diff.square() * keep).sum(1) / keep.sum(1).clamp(min=1)


def frame_variance(frames: torch.Tensor, free: torch.Tensor) -> torch.Tensor:
    """(3,) noise variance per channel of ``frames`` (N, 3, S, S), from consecutive frames'
    differences where both are contact-free (``free``, (N, 1, S, S)); 0 with too few."""
    both = free[:-1] & free[1:]
    usable = both.flatten(1).sum(1) >= MIN_PIXELS
    if not bool(usable.any()):
        return torch.zeros(frames.shape[1])
    frames = frames.float()  # 8-bit frames would wrap around in the difference
    diff = (frames[1:] - frames[:-1])[usable]
    mask = both[usable].expand_as(diff)
    values = diff.transpose(0, 1)[mask.transpose(0, 1)].reshape(diff.shape[1], -1)
    return _mean_square(values) / 2


def frozen_variance(
    frame: torch.Tensor, frames: torch.Tensor, free: torch.Tensor, variance: torch.Tensor
) -> torch.Tensor:
    """(3,) the noise a no-contact ``frame`` (3, S, S) carries frozen in it, next to
    ``frames`` of the same sensor with per-frame noise ``variance``: the mean square of
    their difference away from contacts less the frames' own share, at most ``variance``
    (one capture's worth). A frame of another unit or an average of many comes out lower,
    never higher: a difference that is not noise cannot raise the floor past one capture."""
    diff = (frames.float() - frame.float()[None]).transpose(0, 1)
    mask = free.expand(-1, frames.shape[1], -1, -1).transpose(0, 1)
    if int(mask.sum()) < MIN_PIXELS:
        return torch.zeros_like(variance)
    values = diff[mask].reshape(diff.shape[0], -1)
    return torch.minimum((_mean_square(values) - variance).clamp(min=0.0), variance)


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
            return torch.zeros(len(clean))
        gen = torch.Generator().manual_seed(seed)
        draw = torch.randn((2, *clean.shape), generator=gen)
        model = clean + draw[0] * self.candidate.sqrt()[:, None, None]
        real = clean + draw[1] * self.real.sqrt()[:, None, None]
        return pair_gap([model], Target.of(real))

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
