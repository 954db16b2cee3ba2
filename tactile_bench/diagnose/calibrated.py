"""The ``calibrated`` translator: the gap diagnosis's fitted effects as a simulator, no network.

``fit_pairs`` turns (depth, real foreground) pairs into paired data, runs the diagnosis's
"which" step (``which.explain_gap``) on them and keeps what it selected: the effects and their
fitted parameters, plus white camera noise that tops the model's own pixel noise up to the
real frames' (measured frame to frame, ``metrics.estimate_pixel_noise``, as
``shrink.match_noise`` does). ``translate_foreground`` renders the plain simulator's image of
each depth with those effects added (``simulate.render``) and that noise. Unfitted it is the
plain ``sim`` translator, image for image.

Both sides of a pair share one no-contact frame: the sim is rendered noise-free over the
simulator's frame (``sensor.background.sim_background``) and the real foreground is put on that
same frame, so the diagnosis runs its "composited" case (no background line) and the
translator's foreground is the contact's change alone, ready for any sensor's background.

It lives in ``diagnose/`` rather than ``translators/``: it is built on the diagnosis, a layer
above the translators (docs/architecture.md), and registers through the entry-point group like
any plugin. It only ever sees depth and real foregrounds: no sensor profile, no surrogate.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch.loggers import Logger
from pydantic import Field, field_validator

from tactile_bench.diagnose.candidates import get_candidate
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.report import jsonable
from tactile_bench.diagnose.run import MIN_PAIRS, selected_effects, stratified_split
from tactile_bench.diagnose.scene import (
    FitReference,
    PairScene,
    SimOpticsChoice,
    fit_reference,
    make_scene,
)
from tactile_bench.diagnose.simulate import render
from tactile_bench.diagnose.which import explain_gap
from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import compute_device
from tactile_bench.io import atomic_write_json
from tactile_bench.metrics.noise import estimate_pixel_noise
from tactile_bench.sensor.background import sim_background
from tactile_bench.training import FitReport
from tactile_bench.translators.base import foreground_to_image, image_to_foreground
from tactile_bench.translators.sim import SimConfig, SimTranslator

log = logging.getLogger("tactile_bench")
#: the buffers a fit sets; their shapes depend on the fit, so loading takes the file's shapes
FITTED_BUFFERS = ("record", "noise_std", "lookup_depth", "lookup_target", "sim_table")


class CalibratedConfig(SimConfig):
    """What the diagnosis searches and how the pairs are split (``max_steps`` is ignored)."""

    candidates: list[str] | None = Field(
        default=None,
        description="effects the diagnosis may select (None: its default list, all of them)",
    )
    fit_fraction: float = Field(
        default=0.5, gt=0.0, lt=1.0, description="share of the pairs the effects are fitted on"
    )
    strata: int = Field(
        default=4, ge=1, description="contact-area bins the fit/held split is stratified by"
    )
    chunk: int = Field(default=256, ge=1, description="depths rendered at a time")

    @field_validator("candidates")
    @classmethod
    def _known(cls, names: list[str] | None) -> list[str] | None:
        if names is None:
            return None
        if not names:
            raise ValueError("give at least one effect, or null for the diagnosis's list")
        for name in names:
            try:
                get_candidate(name)
            except TactileBenchError as exc:
                raise ValueError(str(exc)) from None
        return names


def area_strata(depth: torch.Tensor, strata: int) -> list[str]:
    """A stand-in label per pair: its contact area's quantile bin (equal-count bins).

    Translators get no labels. Stratifying by contact area keeps the fit and held-out halves
    alike in what the effects act on (a larger contact carries more of the gap), and for
    braille the area follows the number of dots, so it stands in for the character mix.
    """
    area = (depth > 0).flatten(1).sum(1).cpu()
    order = torch.argsort(area, stable=True)
    bins = torch.empty(len(depth), dtype=torch.long)
    bins[order] = torch.arange(len(depth)) * strata // max(len(depth), 1)
    return [f"area{int(b)}" for b in bins]


def _check_pairs(depth: torch.Tensor, foreground: torch.Tensor) -> None:
    """Depth (N, 1, S, S) and foreground (N, 3, S, S) of one N and S, at least ``MIN_PAIRS``."""
    n, size = len(depth), tuple(depth.shape[-2:])
    if depth.dim() != 4 or depth.shape[1] != 1 or foreground.dim() != 4:
        raise TactileBenchError(
            f"translator 'calibrated': depth must be (N, 1, S, S) and foreground (N, 3, S, S), "
            f"got {tuple(depth.shape)} and {tuple(foreground.shape)}"
        )
    if foreground.shape != (n, 3, *size):
        raise TactileBenchError(
            f"translator 'calibrated': foreground {tuple(foreground.shape)} does not pair with "
            f"depth {tuple(depth.shape)}"
        )
    if n < MIN_PAIRS:
        raise TactileBenchError(
            f"translator 'calibrated': the diagnosis needs at least {MIN_PAIRS} pairs, got {n}"
        )


def _text(buffer: torch.Tensor) -> str:
    return bytes(buffer.tolist()).decode("utf-8")


def _buffer(text: str) -> torch.Tensor:
    return torch.tensor(list(text.encode("utf-8")), dtype=torch.uint8)


class CalibratedTranslator(SimTranslator):
    """Depth -> sim image + the effects the diagnosis fitted + measured noise. Unfitted: sim.

    ``trainable`` stays False: the fit is a search, not Lightning training steps. The fit
    runs on the device the trainer's ``accelerator`` names (the GPU when there is one), and
    renders run where the depths are, with the diagnosis's fitted effects.
    """

    name = "calibrated"
    Config = CalibratedConfig

    def __init__(self, config: CalibratedConfig | dict[str, Any] | None = None) -> None:
        super().__init__(config)
        for name in FITTED_BUFFERS:
            self.register_buffer(name, torch.zeros(0))
        self._record: dict[str, Any] = {}
        # response lookups by device, each refitted once a process
        self._cache: dict[str, dict[str, torch.Tensor]] = {}

    @property
    def fitted(self) -> bool:
        return bool(self._record)

    # ------------------------------------------------------------------ fit
    def fit_pairs(
        self,
        depth: torch.Tensor,
        foreground: torch.Tensor,
        out_dir: Path,
        trainer: dict[str, Any] | None = None,
        loggers: list[Logger] | None = None,
    ) -> FitReport | None:
        """Diagnose the gap of these pairs and keep the selected effects (module docstring).

        Writes ``out_dir/calibration.json`` (the diagnosis's full "which" result); returns
        None: nothing is trained. ``trainer``'s ``enable_progress_bar`` shows the search, its
        ``accelerator`` says where it runs (``hardware.compute_device``): the pairs are moved
        there once, and the fitted state is kept where this module is.
        """
        start = time.perf_counter()
        config: CalibratedConfig = self.config
        _check_pairs(depth, foreground)
        labels = area_strata(depth, config.strata)
        device = compute_device((trainer or {}).get("accelerator"))
        depth = depth.to(device).float().clamp(min=0)
        foreground = foreground.to(device).float()
        size = int(depth.shape[-1])
        background = sim_background(size).to(device)
        sim = self._render_plain(depth, background)
        real = foreground_to_image(foreground, background)
        n = len(depth)
        data = DiagnosisPairs(
            depth, sim, real, background, None, labels, [f"{i:05d}" for i in range(n)]
        )
        fit_idx, held_idx = stratified_split(labels, config.fit_fraction, config.seed)
        progress = bool((trainer or {}).get("enable_progress_bar", True))
        # the depth-split check, the swapped rivals and the Shapley shares change no
        # selection, only what the report says: they would add to the fitting time without
        # changing what is rendered
        which = explain_gap(
            data,
            fit_idx,
            held_idx,
            config.candidates,
            seed=config.seed,
            progress=progress,
            stability=False,
            attribution=False,
        )
        effects = selected_effects(which)
        # what render needs later: the response lookup's fit pairs and the sim optics model,
        # exactly as the diagnosis built them (the fit split's reference)
        self._set_state(fit_reference(data, fit_idx), effects)
        real_std = estimate_pixel_noise(foreground)
        own_std = estimate_pixel_noise(self._model_foreground(depth, self._generator(None)))
        added = torch.zeros(3, device=device)
        if real_std is not None and own_std is not None:
            added = (real_std.square() - own_std.square()).clamp(min=0.0).sqrt() * 255.0
        self.noise_std = added.float().to(self.record.device)
        self._record = {
            "effects": effects,
            "unexplained": float(which.unexplained),
            "residual_flagged": bool(which.residual_flagged),
            "gap_before": float(which.gap_before),
            "gap_after": float(which.gap_after),
            "noise_added": [round(float(v), 4) for v in added],
            "noise_real": None if real_std is None else [float(v) * 255.0 for v in real_std],
            "n_fit": len(fit_idx),
            "n_held": len(held_idx),
            "size": size,
            "fit_seconds": round(time.perf_counter() - start, 2),
        }
        self.record = _buffer(json.dumps(self._record, sort_keys=True))
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_json(
            out_dir / "calibration.json", jsonable({**self._record, "which": which.to_dict()})
        )
        log.info(
            "calibrated: %s in %.1f s, unexplained %.2f",
            list(effects) or "no effect",
            self._record["fit_seconds"],
            which.unexplained,
        )
        return None

    def _set_state(
        self, reference: FitReference, effects: Mapping[str, Mapping[str, float]]
    ) -> None:
        """Keep the lookup's fit pairs (only when ``optical_response`` needs them) and the
        sim optics model; renders share one cache of lookups fitted from them."""
        here = self.record.device  # the module's device, whatever the fit ran on
        empty = torch.zeros(0, device=here)
        response = "optical_response" in effects
        self.lookup_depth = reference.depth.to(here, copy=True) if response else empty
        self.lookup_target = reference.real_change.to(here, copy=True) if response else empty
        table = reference.sim_optics.lookup
        self.sim_table = empty if table is None else table.to(here, copy=True)
        self.noise_std = empty  # measured next, against the model's own noise
        self._record = {"effects": {k: dict(v) for k, v in effects.items()}}
        self._cache = {}

    def fit_diagnostics(self) -> dict[str, Any]:
        """The selection: effects and parameters, unexplained share, noise added, fit time."""
        return dict(self._record)

    # ------------------------------------------------------------------ render
    def _render_plain(self, depth: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
        """The simulator's noise-free image of each depth, in chunks, on its device."""
        out = torch.empty(len(depth), 3, *depth.shape[-2:], device=depth.device)
        for i in range(0, len(depth), self.config.chunk):
            out[i : i + self.config.chunk] = self.optics.render(
                depth[i : i + self.config.chunk].float(), background, None
            )
        return out

    def _scene(self, depth: torch.Tensor, background: torch.Tensor) -> PairScene:
        """The candidate simulator's scene of ``depth`` (the diagnosis's ``make_scene`` of
        noise-free sim images on ``background``), with the fit split's reference kept, on
        ``depth``'s device."""
        device = depth.device
        sim = self.optics.render(depth, background, None)
        names = [""] * len(depth)  # real is not read without a lookup split: sim stands in
        table = self.sim_table.to(device) if self.sim_table.numel() else None
        reference = FitReference(
            self.lookup_depth.to(device),
            self.lookup_target.to(device),
            SimOpticsChoice(table, math.nan, math.nan),
            lookups=self._cache.setdefault(str(device), {}),
        )
        return make_scene(
            DiagnosisPairs(depth, sim, sim, background, None, names, names), None, reference
        )

    def _model_foreground(self, depth: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Foregrounds (N, 3, S, S) of sim + effects + added noise, rendered in chunks on
        ``depth``'s device (the draws come from ``generator``, on the CPU)."""
        size = int(depth.shape[-1])
        fitted_size = self._record.get("size", size)
        if size != fitted_size:
            raise TactileBenchError(
                f"translator {self.name!r}: fitted on {fitted_size} x {fitted_size} depths, "
                f"got {size} x {size}"
            )
        device = depth.device
        background = sim_background(size).to(device)
        effects = self._record["effects"]
        std = (
            self.noise_std.float().to(device)[None, :, None, None]
            if self.noise_std.numel()
            else None
        )
        out = torch.empty(len(depth), 3, size, size, device=device)
        with torch.no_grad():
            for i in range(0, len(depth), self.config.chunk):
                part = depth[i : i + self.config.chunk].float().clamp(min=0)
                image = render(self._scene(part, background), effects, generator)
                if std is not None and bool((std > 0).any()):
                    noise = torch.randn(image.shape, generator=generator).to(device)
                    image = (image + std * noise).clamp(0.0, 255.0)
                out[i : i + len(part)] = image_to_foreground(image, background)
        return out

    def translate_foreground(
        self, depth: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Fitted: sim + effects + noise against the simulator's frame; unfitted: plain sim."""
        if not self.fitted:
            return super().translate_foreground(depth, generator)
        return self._model_foreground(depth, self._generator(generator)).to(depth.device)

    @torch.no_grad()
    def translate(
        self,
        depth: torch.Tensor,
        background: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """The foreground composited on ``background`` ((3, S, S) or one a depth), a chunk at
        a time so only the output is held whole; unfitted: plain sim on it."""
        if not self.fitted:
            return super().translate(depth, background, generator)
        generator = self._generator(generator)
        background = background.float().to(depth.device)
        out = torch.empty(len(depth), 3, *depth.shape[-2:], device=depth.device)
        for i in range(0, len(depth), self.config.chunk):
            part = slice(i, i + self.config.chunk)
            bg = background[part] if background.dim() == 4 else background
            out[part] = foreground_to_image(self._model_foreground(depth[part], generator), bg)
        return out

    # ------------------------------------------------------------------ state
    def _load_from_state_dict(
        self,
        state_dict: dict[str, Any],
        prefix: str,
        local_metadata: dict[str, Any],
        strict: bool,
        missing_keys: list[str],
        unexpected_keys: list[str],
        error_msgs: list[str],
    ) -> None:
        """Fitted buffers take the file's shapes (they depend on the fit), then the record
        is read back; an unreadable one is a load error (RuntimeError), as a wrong shape is."""
        for name in FITTED_BUFFERS:
            value = state_dict.get(prefix + name)
            if isinstance(value, torch.Tensor):
                self._buffers[name] = torch.empty_like(value)
        super()._load_from_state_dict(
            state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs
        )
        self._cache = {}
        self._record = {}
        if not self.record.numel():
            return
        try:
            record = json.loads(_text(self.record))
            for name, params in record["effects"].items():
                get_candidate(name).check(params)
                if not all(
                    isinstance(v, float | int) and math.isfinite(v) for v in params.values()
                ):
                    raise ValueError(f"non-numeric parameter of {name!r}")
        except (ValueError, KeyError, TypeError, AttributeError, TactileBenchError) as exc:
            # raised, not appended to error_msgs: torch puts those below a header line
            raise RuntimeError(f"unreadable calibration record ({exc})") from None
        self._record = record
