"""Rules a recipe must meet beyond its schema, checked for the whole recipe before stage one.

The pydantic models say what type each key has; these say what makes sense: seeds are
32-bit and non-negative, lists name each thing once, counts stay within what the
contact grids hold and what this machine's memory can take, and every ``trainer:`` key is
one ``lightning.Trainer`` takes (found now, not after the earlier stages have run).
"""

from __future__ import annotations

import inspect
import logging
import math
from collections.abc import Callable
from functools import lru_cache
from typing import Any

import lightning as L

from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.contacts import classifier_protocol, finetune_test_protocol
from tactile_bench.guard.args import BYTES_PER_PAIR_PIXEL, MAX_COUNT
from tactile_bench.guard.limits import check_int, check_memory, check_seed, check_unique
from tactile_bench.training import EVERY_KEY

#: config keys whose values are counts, by suffix or prefix of the key
_COUNT_SUFFIXES = ("_pairs", "_steps", "_epochs", "_images", "batch_size", "samples")
#: config keys holding lists that must not repeat an entry
_UNIQUE_KEYS = frozenset({"chars", "objects", "candidates", "sets", "seeds"})
#: bytes one 64 x 64 image of a batch takes through a network (activations included)
_BATCH_BYTES = 64 * 64 * 3 * 4 * 16
#: longest recipe or stage name: it becomes a folder name with a hash appended
MAX_NAME = 100
#: trainer keys that are counts and must be positive (Lightning reads -1 as "no limit")
_POSITIVE_TRAINER_KEYS = ("max_epochs", "max_steps", "min_epochs", "min_steps")


@lru_cache(maxsize=1)
def trainer_keys() -> frozenset[str]:
    """The keyword arguments ``lightning.Trainer`` takes, plus our own."""
    params = inspect.signature(L.Trainer.__init__).parameters
    return frozenset(p for p in params if p != "self") | {EVERY_KEY}


def check_trainer(trainer: dict[str, Any], where: str) -> None:
    """Unknown ``trainer:`` keys and non-positive step/epoch limits are errors now."""
    known = trainer_keys()
    for key in trainer:
        if key not in known:
            close = sorted(k for k in known if k[:4] == str(key)[:4])
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise TactileBenchError(
                f"{where}.trainer.{key}: not a lightning.Trainer argument{hint}"
            )
    for key in (*_POSITIVE_TRAINER_KEYS, EVERY_KEY):
        if key in trainer and trainer[key] is not None:
            check_int(f"{where}.trainer.{key}", trainer[key], 1, MAX_COUNT)
    for key in _OBJECT_TRAINER_KEYS & set(trainer):
        raise TactileBenchError(
            f"{where}.trainer.{key}: set by tactile_bench for each stage, not by a recipe"
        )
    try_trainer(trainer, where)


#: Trainer arguments tactile_bench passes itself: Python objects, and each stage's folder
_OBJECT_TRAINER_KEYS = frozenset({"logger", "callbacks", "plugins", "default_root_dir"})


def try_trainer(trainer: dict[str, Any], where: str) -> None:
    """Build a ``lightning.Trainer`` from the settings now: a wrong precision, strategy,
    accelerator or device count fails here, not after the stages before its first fit."""
    settings = {k: v for k, v in trainer.items() if k != EVERY_KEY}
    settings |= {
        "logger": False,
        "enable_checkpointing": False,
        "enable_progress_bar": False,
        "enable_model_summary": False,
    }
    quiet = [logging.getLogger(n) for n in ("lightning.pytorch", "lightning.fabric")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.ERROR)  # its "GPU available: False" lines are for real fits
    try:
        L.Trainer(**settings)
    except Exception as exc:  # Lightning raises ValueError, MisconfigurationException, ...
        reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise TactileBenchError(
            f"{where}.trainer: lightning.Trainer refuses it: {reason}"
        ) from None
    finally:
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)


def _walk(value: Any, key: str, where: str) -> None:
    """Generic rules by key name, at any depth of a stage config."""
    name = key.rsplit(".", 1)[-1]
    if name == "seed" or name.endswith("_seed"):
        check_seed(f"{where}.{key}", value)
    if name == "seeds" and isinstance(value, list):
        for i, seed in enumerate(value):
            check_seed(f"{where}.{key}[{i}]", seed)
    if name in _UNIQUE_KEYS:
        check_unique(f"{where}.{key}", value)
    counted = name.startswith("n_") or name.endswith(_COUNT_SUFFIXES)
    if counted and isinstance(value, int) and not isinstance(value, bool):
        check_int(f"{where}.{key}", value, 0, MAX_COUNT)
    if isinstance(value, float) and not math.isfinite(value):
        raise TactileBenchError(f"{where}.{key}: must be a finite number, got {value}")
    if name.endswith("batch_size") and isinstance(value, int) and value > 0:
        # one batch of 64 x 64 RGB floats through a network holds ~16 such tensors
        check_memory(f"{where}.{key}", f"a batch of {value} images", float(value) * _BATCH_BYTES)
    if isinstance(value, dict):
        for k, v in value.items():
            _walk(v, f"{key}.{k}", where)


# ----------------------------------------------------------------------------- per kind
def _braille_data(config: Any, where: str) -> None:
    chars = tuple(config.chars)
    n_chars = len(chars)
    grid = len(classifier_protocol(chars))
    if config.n_classifier is not None and config.n_classifier > grid:
        raise TactileBenchError(
            f"{where}.n_classifier: {config.n_classifier} asked, but the classifier grid of "
            f"{n_chars} characters holds {grid} contacts (leave it out for all of them)"
        )
    fine = len(finetune_test_protocol(chars))
    if config.source == "surrogate" and config.n_finetune + config.n_test > fine:
        raise TactileBenchError(
            f"{where}.n_finetune + n_test: {config.n_finetune} + {config.n_test} asked, but the "
            f"fine-tune/test grid of {n_chars} characters holds {fine} contacts"
        )
    n = config.n_finetune + config.n_test + (config.n_classifier or grid) + config.n_classifier_test
    size = config.image_size
    check_memory(f"{where}.n_*", f"{n} contacts of {size} x {size}", float(n) * size * size * 10)


def _ycb_slide_data(config: Any, where: str) -> None:
    size = config.image_size
    check_memory(
        f"{where}.n_pairs",
        f"{config.n_pairs} pairs of {size} x {size}",
        float(config.n_pairs) * size * size * BYTES_PER_PAIR_PIXEL,
    )


#: per stage kind: rules that need more than one key (grid sizes, memory)
STAGE_RULES: dict[str, Callable[[Any, str], None]] = {
    "braille_data": _braille_data,
    "ycb_slide_data": _ycb_slide_data,
}


def check_name(name: str, where: str) -> None:
    """A recipe or stage name short enough to be a folder name (with a hash appended)."""
    if len(name) > MAX_NAME:
        raise TactileBenchError(f"{where}: a name of {len(name)} characters; at most {MAX_NAME}")


def check_stage(kind: str, config: Any, where: str) -> None:
    """Generic rules on every key of a stage's config, then the kind's own rules."""
    for key, value in config.model_dump(mode="python").items():
        _walk(value, key, where)
    rule = STAGE_RULES.get(kind)
    if rule is not None:
        rule(config, where)
