"""A fitted profile as the three things calibrate does with it: held in memory, written as
YAML, scored against held-out pairs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch.nn.functional as F

from tactile_bench.calibrate.fit import ProfileFit
from tactile_bench.diagnose.paired import DiagnosisPairs
from tactile_bench.diagnose.scene import OVERSAMPLE
from tactile_bench.effects.sensors import SensorFit
from tactile_bench.sensor.surrogate import SurrogateDigit


def in_memory_profile(fit: ProfileFit, name: str) -> SurrogateDigit:
    """The profile ``fit`` describes, without writing it (the curve's points)."""
    sensor = SensorFit.from_mapping(name, fit.sensor, "calibrate")
    return SurrogateDigit(fit.effects, unit=name, name=name, sensor_fit=sensor)


def write_fitted_profile(path: Path, fit: ProfileFit, name: str, what: str) -> Path:
    """``fit`` as a profile YAML (``sensor.profile_io.write_profile``)."""
    from tactile_bench.sensor.profile_io import write_profile

    described = ", ".join(fit.selected) or "no effect"
    description = (
        f"Calibrated by `tactile_bench calibrate` from {fit.n_pairs} pairs of {what} "
        f"(the diagnosis selected: {described}); optical response, no-contact field and "
        "camera noise fitted on those pairs only."
    )
    return write_profile(
        path, name=name, description=description, effects=fit.effects, sensor=fit.sensor
    )


def score_heldout(profile: SurrogateDigit, held: DiagnosisPairs, seed: int) -> dict[str, Any]:
    """The profile and the plain sim against the held-out real frames
    (``sensor.pair_scoring.score_profile``); depth at twice the size, as the profile renders."""
    from tactile_bench.sensor.pair_scoring import score_profile

    depth = F.interpolate(held.depth.float(), scale_factor=OVERSAMPLE, mode="bilinear")
    return score_profile(
        profile,
        depth,
        held.real.float(),
        held.background.float(),
        tuple(held.gel_mm),
        size=held.size,
        seed=seed,
    )
