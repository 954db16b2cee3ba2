"""What a profile takes from the fit half of the user's pairs, and nothing else.

``fit_sensor_profile`` runs the steps in order, each logged with its time:

1. **background**: cosine (DCT) coefficients of ``background.png`` (``grounding.
   fit_background_dct``), K terms per axis; K is the one whose field best reproduces the
   fit frames' pixels far from any contact (other captures than the no-contact frame, so a
   K that copies that one capture's noise does not win), the smallest within 1% of the best;
   then corrected so that the profile's own no-contact render, through whatever gain, tone
   curve or lens it applies, is that field (``match_no_contact``);
2. **selection**: the diagnosis's "which" step (``diagnose.which.explain_gap``) on the fit
   half alone, with its own inner fit / held-out split; the selected effects keep their
   fitted parameters (``diagnose.run.selected_effects``);
3. **geometry**: the selected (and unselected) deterministic gel geometry refitted for the
   contact region by cross-validation on the fit pairs (``geometry.refit_geometry``);
4. **lookup**: the optical response (F, 3, 6) fitted by least squares on every fit pair,
   on the gel surface the profile itself renders (the selected deterministic geometry at
   twice the size, area-averaged back), and the LED azimuths from its first harmonic;
5. **noise**: camera noise as the selection fitted it, else as ``press_grounding.
   frame_noise`` measures it on the fit frames (read noise only).

``profile_effects`` maps the selection onto profile effects: every parameter the candidate
held at neutral written out (a profile fills missing ones with defaults, not neutral
values), and ``optical_response`` at blend 1 on the profile's own response weights. What a
profile cannot carry is dropped with the reason: a registration of the pairs' depth, the
diagnosis's own modelling (dust read from the measured frame, a codec at the stored size),
and, when the response was not selected, optics effects fitted to reshape the sim's own
colour change, which the profile's lookup replaces. When the response was selected, the
other effects were fitted on top of the same lookup and the profile applies them so.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from tactile_bench.calibrate.geometry import profile_surface, refit_geometry
from tactile_bench.diagnose.candidates import get_candidate
from tactile_bench.diagnose.noise import contact_free
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.run import selected_effects, stratified_split
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.effects import EFFECT_ORDER, EFFECTS
from tactile_bench.effects.sensors import SensorFit
from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.press_grounding import frame_noise, led_azimuths
from tactile_bench.sensor.response_fit import fit_response
from tactile_bench.sensor.surrogate import SurrogateDigit

log = logging.getLogger("tactile_bench")

BACKGROUND_KS = (2, 4, 6, 8, 12, 16, 24, 32)  # cosine terms per axis tried
FALLBACK_K = 8  # press_grounding's, when no fit frame has pixels far from its contact
K_TOLERANCE = 0.01  # the smallest K whose MSE is within this share of the best K's
MIN_FREE_PIXELS = 64  # fewer contact-free pixels than this cannot judge K
INNER_FIT_FRACTION = 0.5  # the diagnosis's own default share of pairs it fits on
MIN_SELECTION_SPLIT = 2  # explain_gap needs this many pairs on each side of its split
RESPONSE = "optical_response"
NOISE = "camera_noise"
NOISE_PARAM = "read_noise"
MATCH_ROUNDS = 8  # corrections of the field for what the profile's effects do to it
MATCH_RMS = 0.1  # grey levels: a no-contact frame this close to the field is matched
PROBE = "calibration"  # the sensor name of the in-memory profile that renders the frame
DCT_DECIMALS, WEIGHT_DECIMALS = 2, 3  # as press_grounding.fit_sensor rounds them


@dataclass
class ProfileFit:
    """What the fit half gives a profile, and how it was found."""

    effects: dict[str, dict[str, float]]  # the profile's effects and their parameters
    sensor: dict[str, Any]  # the profile's sensor block
    selected: dict[str, dict[str, float]]  # what the diagnosis selected, as it fitted it
    dropped: dict[str, str]  # parts of the selection a profile cannot carry, and why
    background: dict[str, Any]  # K chosen, the MSE of every K tried
    noise: dict[str, Any]  # the camera noise used and where it came from
    selection: dict[str, Any]  # the inner split and what the selection left
    geometry: dict[str, Any]  # the contact-region refit of the gel geometry (geometry.py)
    timing_s: dict[str, float] = field(default_factory=dict)

    @property
    def n_pairs(self) -> int:
        return int(self.selection["n_fit"] + self.selection["n_heldout"])


# ----------------------------------------------------------------------------- background
def _basis(n: int, k: int) -> np.ndarray:
    """(n, k) cosines cos(pi i (j + 0.5) / n), the terms of ``grounding.fit_background_dct``."""
    t = (np.arange(n) + 0.5) / n
    return np.stack([np.cos(np.pi * i * t) for i in range(k)], 1)


def dct_field(coef: np.ndarray, h: int, w: int) -> np.ndarray:
    """(H, W, 3) field of cosine coefficients (3, K, K), as ``fit_background_dct`` fits it."""
    k = coef.shape[-1]
    return np.einsum("yk,xl,ckl->yxc", _basis(h, k), _basis(w, k), coef, optimize=True)


def fit_dct(image: np.ndarray, k: int) -> np.ndarray:
    """``grounding.fit_background_dct`` (least-squares (3, K, K) coefficients of an (H, W,
    3) frame) axis by axis: the design is the Kronecker product of the two axes' cosines,
    so its pseudo-inverse is theirs; milliseconds where the full design takes seconds."""
    h, w = image.shape[:2]
    py, px = np.linalg.pinv(_basis(h, k)), np.linalg.pinv(_basis(w, k))
    return np.einsum("ky,yxc,lx->ckl", py, image, px, optimize=True)


def fit_background(
    background: torch.Tensor, depth: torch.Tensor, real: torch.Tensor
) -> tuple[np.ndarray, dict[str, Any]]:
    """Cosine coefficients (3, K, K) of the no-contact frame (3, S, S), K chosen on the fit
    frames ``real`` (N, 3, S, S) away from their contacts (``depth`` (N, 1, S, S))."""
    frame = background.permute(1, 2, 0).double().numpy()
    h, w = frame.shape[:2]
    ks = [k for k in BACKGROUND_KS if k <= min(h, w)]
    free = contact_free(depth)[:, 0].numpy()  # (N, S, S)
    if int(free.sum()) < MIN_FREE_PIXELS:
        k = min(FALLBACK_K, min(h, w))
        why = f"no fit frame has {MIN_FREE_PIXELS} pixels far from its contact: K = {k}"
        return fit_dct(frame, k), {"k": k, "chosen_by": why, "mse": {}}
    pixels = real.permute(0, 2, 3, 1).double().numpy()[free]  # (P, 3)

    def mse(field: np.ndarray) -> float:
        return float(((np.broadcast_to(field, (len(free), h, w, 3))[free] - pixels) ** 2).mean())

    coefs = {k: fit_dct(frame, k) for k in ks}
    scores = {k: mse(dct_field(c, h, w)) for k, c in coefs.items()}
    best = min(scores.values())
    k = min(k for k, s in scores.items() if s <= best * (1 + K_TOLERANCE))
    info = {
        "k": k,
        "chosen_by": "smallest K within 1% of the best MSE against the fit frames' pixels "
        "far from any contact",
        "mse": {str(key): round(s, 3) for key, s in scores.items()},
        "measured_frame_mse": round(mse(frame), 3),
    }
    return coefs[k], info


# ----------------------------------------------------------------------------- selection
def inner_split(fit: DiagnosisPairs, seed: int, what: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The selection's own fit / held-out split of the fit half (the diagnosis's default
    share); too few pairs on a side is a one-line error naming ``what``."""
    if len(fit) >= 4:
        a, b = stratified_split(fit.labels, INNER_FIT_FRACTION, seed)
        if min(len(a), len(b)) >= MIN_SELECTION_SPLIT:
            return a, b
    raise TactileBenchError(
        f"{what}: {len(fit)} fit pairs leave the effect selection fewer than "
        f"{MIN_SELECTION_SPLIT} pairs to fit or to check on; add pairs or lower --holdout"
    )


def select_effects(
    fit: DiagnosisPairs,
    seed: int,
    candidates: Sequence[str] | None,
    progress: bool,
    what: str,
) -> tuple[dict[str, dict[str, float]], dict[str, Any]]:
    """The diagnosis's selection on the fit half (its inner split): effects with their
    fitted parameters, and what it reports. The depth-split check and the attribution
    (swapped rivals, Shapley shares) change no selected parameter, so they are not run."""
    a, b = inner_split(fit, seed, what)
    which = explain_gap(
        fit, a, b, candidates, seed, progress=progress, stability=False, attribution=False
    )
    report = {
        "n_fit": len(a),
        "n_heldout": len(b),
        "ranking": [{"effect": r.effect, "shrink": round(r.shrink, 4)} for r in which.ranking],
        "gap_before": which.gap_before,
        "gap_after": which.gap_after,
        "unexplained": which.unexplained,
        "sim_optics": which.sim_optics,
    }
    return selected_effects(which), report


# ----------------------------------------------------------------------------- profile
def profile_effects(
    selected: Mapping[str, Mapping[str, float]],
) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """The selection as profile effects (module docstring), and what was dropped and why."""
    effects: dict[str, dict[str, float]] = {}
    dropped: dict[str, str] = {}
    for name in [n for n in EFFECT_ORDER if n in selected]:
        cand, effect = get_candidate(name), EFFECTS[name]
        if cand.acts_on == "pose":
            dropped[name] = "a misregistration of the pairs' depth, not a property of the sensor"
            continue
        if cand.acts_on == "optics" and RESPONSE not in selected:
            dropped[name] = (
                "fitted to reshape the sim's own colour change, which the profile's response "
                "lookup (fitted to the real change) replaces"
            )
            continue
        own = {p.name for p in effect.params}
        for key in sorted(set(selected[name]) - own):
            dropped[f"{name}.{key}"] = (
                f"the diagnosis's own modelling ({cand.note or 'no note'}); no profile parameter"
            )
        full = {k: float(v) for k, v in cand.full_params(selected[name]).items() if k in own}
        if effect.is_neutral(effect.validate(full)) and name != RESPONSE:
            dropped.setdefault(name, "neutral once the diagnosis's own modelling is dropped")
            continue
        effects[name] = full
    effects[RESPONSE] = {"blend": 1.0}  # the profile's own lookup, in place of Phong shading
    return {n: effects[n] for n in EFFECT_ORDER if n in effects}, dropped


def fit_lookup(
    fit: DiagnosisPairs, effects: Mapping[str, Mapping[str, float]], what: str
) -> np.ndarray:
    """The response lookup (F, 3, 6) of the real frames' change from the no-contact frame,
    on every fit pair, under the profile's geometry (as the diagnosis fits it)."""
    gel = (float(fit.gel_mm[0]), float(fit.gel_mm[1]))
    surface = profile_surface(fit.depth, effects, gel)
    with torch.no_grad():
        try:
            return fit_response(surface, fit.real - fit.background[None], gel)
        except ValueError:
            raise TactileBenchError(
                f"{what}: no fit pair has a contact (depth 0 everywhere): nothing to fit the "
                "optical response on"
            ) from None


def camera_noise(
    fit: DiagnosisPairs, selected: Mapping[str, Mapping[str, float]]
) -> tuple[dict[str, float] | None, dict[str, Any]]:
    """The camera noise the profile adds: the selection's fit when it selected one, else
    the read noise ``press_grounding.frame_noise`` measures on the fit frames (None: none)."""
    if NOISE in selected:
        return None, {"source": "selected by the diagnosis", **selected[NOISE]}
    sigma = frame_noise(fit.real, fit.background, fit.depth)
    high = EFFECTS[NOISE].param(NOISE_PARAM).high
    sigma = round(min(max(sigma, 0.0), high), 2)
    info = {
        "source": "measured on the fit frames by press_grounding.frame_noise",
        NOISE_PARAM: sigma,
    }
    if sigma <= 0:
        return None, info
    full = get_candidate(NOISE).full_params({NOISE_PARAM: sigma})
    return {k: float(v) for k, v in full.items()}, info


def _no_contact_frame(
    effects: Mapping[str, Mapping[str, float]], sensor: Mapping[str, Any], size: int
) -> np.ndarray:
    """(S, S, 3) the no-contact frame a profile of ``effects`` and ``sensor`` renders."""
    own = SensorFit.from_mapping(PROBE, sensor, "calibrate")
    profile = SurrogateDigit(effects, unit=PROBE, name=PROBE, sensor_fit=own)
    return profile.background(size).permute(1, 2, 0).double().numpy()


def match_no_contact(
    effects: Mapping[str, Mapping[str, float]], sensor: Mapping[str, Any], size: int
) -> tuple[np.ndarray, list[float]]:
    """Cosine coefficients whose profile, through its own effects (a gain, a tone curve,
    a lens), renders the fitted field as its no-contact frame, as the candidate simulator
    composites onto the measured frame; and the RMS of each round's mismatch. Each round
    adds the fit of what is left (a fixed point: a field no effect changes stops at once)."""
    coef = np.asarray(sensor["background_dct"], dtype=np.float64)
    target = dct_field(coef, size, size)
    best, rms = coef, []
    for _ in range(MATCH_ROUNDS + 1):
        residual = target - _no_contact_frame(effects, {**sensor, "background_dct": coef}, size)
        rms.append(round(float(np.sqrt((residual**2).mean())), 3))
        if rms[-1] > min(rms):  # moving away (a clamp at 0 or 255): keep the best so far
            break
        best = coef
        if rms[-1] < MATCH_RMS or len(rms) > MATCH_ROUNDS:
            break
        coef = coef + fit_dct(residual, coef.shape[-1])
    return best, rms


def _timed(timing: dict[str, float], step: str, start: float) -> float:
    timing[step] = round(time.perf_counter() - start, 2)
    return timing[step]


def fit_sensor_profile(
    fit: DiagnosisPairs,
    seed: int = 0,
    candidates: Sequence[str] | None = None,
    progress: bool = True,
    what: str = "pairs",
) -> ProfileFit:
    """Every part of a profile from ``fit`` alone (module docstring); ``what`` names the
    pairs in errors."""
    timing: dict[str, float] = {}
    t = time.perf_counter()
    dct, bg_info = fit_background(fit.background, fit.depth, fit.real)
    secs = _timed(timing, "background", t)
    log.info("background: %d x %d cosine terms (%.1f s)", bg_info["k"], bg_info["k"], secs)

    t = time.perf_counter()
    selected, selection = select_effects(fit, seed, candidates, progress, what)
    secs = _timed(timing, "selection", t)
    log.info("selection: %s (%.1f s)", ", ".join(selected) or "nothing selected", secs)

    t = time.perf_counter()
    effects, dropped = profile_effects(selected)
    effects, geometry = refit_geometry(fit, effects)
    secs = _timed(timing, "geometry", t)
    log.info(
        "geometry: contact CV MSE %.1f -> %.1f (%.1f s)",
        geometry["cv_contact_mse_before"],
        geometry["cv_contact_mse_after"],
        secs,
    )

    t = time.perf_counter()
    weights = fit_lookup(fit, effects, what)
    noise, noise_info = camera_noise(fit, selected)
    if noise is not None:
        effects[NOISE] = noise
        effects = {n: effects[n] for n in EFFECT_ORDER if n in effects}
    sensor = {
        "gel_mm": [round(float(v), 4) for v in fit.gel_mm],
        "background_dct": dct,
        "response_weights": np.round(weights, WEIGHT_DECIMALS).tolist(),
        "led_azimuth_deg": list(led_azimuths(weights)),
    }
    dct, bg_info["no_contact_rms"] = match_no_contact(effects, sensor, fit.size)
    sensor["background_dct"] = np.round(dct, DCT_DECIMALS).tolist()
    secs = _timed(timing, "lookup", t)
    log.info(
        "lookup: optical response fitted on %d pairs, noise %s (%.1f s)",
        len(fit),
        noise_info.get(NOISE_PARAM, "as selected"),
        secs,
    )
    selected = {k: dict(v) for k, v in selected.items()}
    return ProfileFit(
        effects, sensor, selected, dropped, bg_info, noise_info, selection, geometry, timing
    )
