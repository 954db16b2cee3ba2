"""What a stage kind is, and what a running stage sees."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from tactile_bench.errors import TactileBenchError
from tactile_bench.sensor.surrogate import SurrogateDigit


class StageConfig(BaseModel):
    """Base of every stage config: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid")


@dataclass(frozen=True)
class ConfigKey:
    """One key a recipe may set on a stage: its dotted name, default and description."""

    key: str
    default: str
    description: str


def config_keys(model: type[BaseModel], prefix: str = "") -> list[ConfigKey]:
    """Every key of a stage config, nested configs as ``classifier.lr``: what ``list stages``
    prints, so a recipe's keys are documented where they are defined (``Field(description)``).
    """
    keys = []
    for name, field_info in model.model_fields.items():
        sub = field_info.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            keys += config_keys(sub, f"{prefix}{name}.")
            continue
        default = "required" if field_info.is_required() else repr(field_info.get_default())
        keys.append(ConfigKey(prefix + name, default, field_info.description or ""))
    return keys


@dataclass
class StageResult:
    """A finished stage: where its files are, what they are, and a few figures it measured."""

    name: str
    kind: str
    directory: Path
    outputs: dict[str, str]
    metrics: dict[str, Any]
    manifest_hash: str
    wall_time_s: float
    cached: bool = False
    peak_rss_mib: float | None = None  # its process's peak RSS at the end of the stage

    def path(self, output: str) -> Path:
        """Absolute path of a named output file."""
        return self.directory / self.outputs[output]


@dataclass
class StageContext:
    """Everything a stage may read: its directory, config, upstream results and run settings."""

    name: str
    directory: Path
    config: Any
    inputs: dict[str, list[StageResult]]
    seed: int
    trainer: dict[str, Any]
    run_dir: Path
    recipe_dir: Path = Path(".")
    progress: bool = True
    previous: list[StageResult] = field(default_factory=list)  # finished stages before it

    def input(self, slot: str) -> StageResult:
        """The single stage feeding ``slot``."""
        return self.inputs[slot][0]

    def optional_input(self, slot: str) -> StageResult | None:
        results = self.inputs.get(slot) or []
        return results[0] if results else None


def resolve_source(source: str, base_dir: Path) -> Path:
    """A data path as written in a recipe: absolute, or relative to the recipe's folder."""
    path = Path(source).expanduser()
    return path if path.is_absolute() else (base_dir / path).resolve()


def real_sensor(profile: str, base_dir: Path) -> SurrogateDigit:
    """A data stage's ``real_sensor``: a built-in profile name, or a YAML path read relative
    to the recipe's folder (as every other path in a recipe), not the working directory."""
    if Path(profile).suffix:
        return SurrogateDigit.from_profile(resolve_source(profile, base_dir))
    return SurrogateDigit.from_profile(profile)


def check_real_sensor(profile: str, base_dir: Path) -> None:
    """A data stage's ``real_sensor`` must load as a surrogate profile; the error names the key."""
    try:
        real_sensor(profile, base_dir)
    except TactileBenchError as exc:
        raise TactileBenchError(f"real_sensor: {exc}") from None


def _no_check(config: Any, base_dir: Path) -> None:
    return None


@dataclass(frozen=True)
class StageKind:
    """A registered kind of stage: typed config, named inputs, and the function that runs it.

    ``run`` returns ``(outputs, metrics)``: outputs maps names to files it wrote
    in ``ctx.directory`` (hashed into the manifest); metrics are JSON figures.
    ``exactly_one_of`` names input slots of which a recipe must connect exactly one.
    ``publish`` names outputs copied to the run directory's root (results, reports).
    ``check`` validates a config against the world (files, registries) before any
    work starts and raises TactileBenchError("key: problem").
    ``precision_dependent``: its results depend on the precision its networks train or
    sample in, which ``precision: auto`` picks per machine; its cache key then includes what
    ``auto`` resolves to here, so another machine does not silently reuse it. Stages that run
    networks only in fixed fp32 leave it False (their inputs' hashes already rerun them when
    an upstream stage's outputs change), and so do data stages, cached across machines.
    ``waits_for_earlier``: it reads every stage listed before it (``ctx.previous``), so
    with ``jobs`` > 1 it starts only when all of them have finished.
    ``fits``: it trains networks with ``training.resumable_fit`` on the recipe's trainer
    settings. Under a launch of several processes (``pipeline.launch``) every rank runs it
    (its fits are DDP fits), and its cache key records how many processes trained, which
    sets the effective batch; any other stage runs on rank 0 alone.
    """

    name: str
    description: str
    config_model: type[BaseModel]
    run: Callable[[StageContext], tuple[dict[str, str], dict[str, Any]]]
    input_slots: dict[str, bool] = field(default_factory=dict)
    check: Callable[[Any, Path], None] = _no_check
    exactly_one_of: tuple[str, ...] = ()
    publish: tuple[str, ...] = ()
    precision_dependent: bool = False
    waits_for_earlier: bool = False
    fits: bool = False
