"""Recipes: YAML files of named stages with typed configs, validated before any work starts.

```yaml
name: sim_only
seed: 0
stages:
  - name: braille            # unique; later stages refer to it
    kind: braille_data       # a registered stage kind (see `tactile_bench list stages`)
    config: {n_test: 837}
  - name: classify_sim
    kind: classify
    inputs: {data: braille}
    config: {train_images: sim}
```
Any problem (unknown key, wrong type, missing file, unknown translator, a
reference to a stage that does not come earlier) is a TactileBenchError naming
the file and the key.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.limits import check_seed
from tactile_bench.guard.safe_yaml import load_yaml_file, load_yaml_text
from tactile_bench.pipeline.recipe_rules import check_name, check_stage, check_trainer
from tactile_bench.pipeline.stages import STAGES, StageKind
from tactile_bench.pipeline.stages.base import config_keys


class _StageDoc(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
    kind: str
    inputs: dict[str, str | list[str]] = {}
    config: dict[str, Any] = {}


class RaySettings(BaseModel):
    """``ray:`` of a recipe run with ``executor: ray`` (``pipeline.ray_executor``)."""

    model_config = ConfigDict(extra="forbid")
    address: str | None = None  # the cluster (default: RAY_ADDRESS, else a local instance)
    cpus_per_stage: int = Field(default=1, ge=1, le=1024)


class _RecipeDoc(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
    description: str = ""
    seed: int = 0
    run_dir: str | None = None
    trainer: dict[str, Any] = {}
    jobs: int = Field(default=1, ge=1, le=64)
    executor: Literal["local", "ray"] = "local"
    ray: RaySettings = RaySettings()
    stages: list[_StageDoc] = Field(min_length=1)


@dataclass
class Stage:
    """One validated stage: its kind, typed config and the names of the stages it reads."""

    name: str
    kind: StageKind
    config: BaseModel
    inputs: dict[str, list[str]]


@dataclass
class Recipe:
    """A validated recipe, ready for the runner."""

    path: Path
    name: str
    seed: int
    run_dir: Path
    trainer: dict[str, Any]
    stages: list[Stage] = field(default_factory=list)
    description: str = ""
    jobs: int = 1  # stages run side by side at most (pipeline.side_by_side)
    executor: str = "local"  # local: this machine; ray: tasks on a Ray cluster
    ray: RaySettings = field(default_factory=RaySettings)

    def stage(self, name: str) -> Stage:
        for stage in self.stages:
            if stage.name == name:
                return stage
        raise TactileBenchError(f"{self.path}: no stage named {name!r}")


def _loc(parts: tuple[Any, ...] | list[Any]) -> str:
    return ".".join(str(p) for p in parts)


def _first_error(exc: ValidationError, prefix: str) -> str:
    first = exc.errors()[0]
    key = _loc([prefix, *first["loc"]] if prefix else first["loc"])
    return f"{key}: {first['msg']}"


def _unknown_key_hint(exc: ValidationError, kind: str, model: type[BaseModel]) -> str:
    """For a key the stage does not take: the nearest key it does take, with what it means,
    so a typo is answered with the fix, not only with the refusal."""
    first = exc.errors()[0]
    if first["type"] != "extra_forbidden":
        return ""
    keys = {k.key: k for k in config_keys(model)}
    typed = _loc(first["loc"])
    near = difflib.get_close_matches(typed, list(keys), n=1)
    guess = f"; did you mean {near[0]} ({keys[near[0]].description})?" if near else ""
    return f"{guess} (`tactile_bench list stages` shows every key of {kind})"


def apply_overrides(doc: dict[str, Any], overrides: list[str], path: Path) -> dict[str, Any]:
    """Apply ``--set KEY=VALUE``: ``seed=1``, ``trainer.max_epochs=2`` or ``STAGE.key.sub=v``.

    Values are parsed as YAML, so numbers, booleans and lists keep their types.
    """
    stages = {s.get("name"): s for s in doc.get("stages", []) if isinstance(s, dict)}
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise TactileBenchError(f"--set {item!r}: expected KEY=VALUE")
        value = load_yaml_text(raw, f"--set {key}")
        head, *rest = key.split(".")
        if head in stages:
            target = stages[head].setdefault("config", {})
            if not rest:
                raise TactileBenchError(f"--set {item!r}: name a config key of stage {head!r}")
        elif head in _RecipeDoc.model_fields:
            target, rest = doc, [head, *rest]
        else:
            raise TactileBenchError(f"{path}: --set {key}: no stage or recipe key named {head!r}")
        for part in rest[:-1]:
            node = target.setdefault(part, {})
            if not isinstance(node, dict):
                raise TactileBenchError(f"{path}: --set {key}: {part!r} is not a mapping")
            target = node
        target[rest[-1]] = value
    return doc


def _unshared(node: Any) -> Any:
    """A copy with no shared sub-mappings: YAML anchors (``&base`` / ``<<: *base``) alias
    nested dicts, so a ``--set`` on one stage would otherwise change every stage using them."""
    if isinstance(node, dict):
        return {k: _unshared(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_unshared(v) for v in node]
    return node


def load_recipe(path: str | Path, overrides: list[str] | None = None) -> Recipe:
    """Read, override and validate a recipe; every error names the file and the key."""
    path = Path(path)
    # a regular file only, aliases bounded, a key written twice refused (guard.safe_yaml)
    raw = load_yaml_file(path, "recipe")
    if not isinstance(raw, dict):
        raise TactileBenchError(f"{path}: a recipe is a mapping with 'name' and 'stages'")
    raw = apply_overrides(_unshared(raw), overrides or [], path)
    try:
        doc = _RecipeDoc(**raw)
    except ValidationError as exc:
        raise TactileBenchError(f"{path}: {_first_error(exc, '')}") from None
    except TypeError as exc:
        raise TactileBenchError(f"{path}: {exc}") from None

    check_seed(f"{path}: seed", doc.seed)
    check_name(doc.name, f"{path}: name")
    check_trainer(doc.trainer, str(path))
    run_dir = Path(doc.run_dir) if doc.run_dir else Path("runs") / doc.name
    recipe = Recipe(
        path,
        doc.name,
        doc.seed,
        run_dir,
        doc.trainer,
        [],
        doc.description,
        doc.jobs,
        doc.executor,
        doc.ray,
    )
    seen: set[str] = set()
    for index, stage_doc in enumerate(doc.stages):
        where = f"{path}: stages[{index}] ({stage_doc.name})"
        if stage_doc.name in seen:
            raise TactileBenchError(f"{where}: duplicate stage name")
        check_name(stage_doc.name, f"{where}.name")
        kind = STAGES.get(stage_doc.kind)
        if kind is None:
            raise TactileBenchError(
                f"{where}.kind: unknown stage kind {stage_doc.kind!r} "
                f"(known: {', '.join(sorted(STAGES))})"
            )
        try:
            config = kind.config_model(**stage_doc.config)
        except ValidationError as exc:
            hint = _unknown_key_hint(exc, kind.name, kind.config_model)
            raise TactileBenchError(f"{where}.config.{_first_error(exc, '')}{hint}") from None
        inputs = {
            slot: [refs] if isinstance(refs, str) else list(refs)
            for slot, refs in stage_doc.inputs.items()
        }
        for slot in inputs:
            if slot not in kind.input_slots:
                raise TactileBenchError(
                    f"{where}.inputs.{slot}: stage kind {stage_doc.kind!r} takes inputs "
                    f"{sorted(kind.input_slots)}"
                )
        for slot, required in kind.input_slots.items():
            if required and slot not in inputs:
                raise TactileBenchError(f"{where}.inputs.{slot}: required input missing")
        if kind.exactly_one_of and sum(s in inputs for s in kind.exactly_one_of) != 1:
            raise TactileBenchError(
                f"{where}.inputs: connect exactly one of {list(kind.exactly_one_of)}"
            )
        for slot, refs in inputs.items():
            for ref in refs:
                if ref not in seen:
                    raise TactileBenchError(
                        f"{where}.inputs.{slot}: {ref!r} is not an earlier stage"
                    )
        try:
            kind.check(config, path.parent)
        except TactileBenchError as exc:
            raise TactileBenchError(f"{where}.config.{exc}") from None
        check_stage(kind.name, config, f"{where}.config")  # recipe_rules: bounds, duplicates
        recipe.stages.append(Stage(stage_doc.name, kind, config, inputs))
        seen.add(stage_doc.name)
    return recipe
