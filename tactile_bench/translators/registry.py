"""Find translators through the entry-point group ``tactile_bench.translators``.

Built-ins register exactly like third-party plugins (in this project's own
pyproject), so there is one path for both and no model-name switch anywhere.
A name claimed by two different objects is an error, never a silent override;
a plugin that fails to import breaks only itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

import torch

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.files import require_not_special
from tactile_bench.translators.base import Translator, TranslatorConfig

GROUP = "tactile_bench.translators"


@dataclass(frozen=True)
class TranslatorEntry:
    """One registered translator: its name, where it lives, and which package provides it."""

    name: str
    target: str
    distribution: str

    def load(self) -> type[Translator]:
        """Import the class; a broken or non-Translator plugin is a one-line error."""
        try:
            obj = EntryPoint(name=self.name, value=self.target, group=GROUP).load()
        except (Exception, SystemExit) as exc:  # a plugin calling sys.exit() on import too
            reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
            raise TactileBenchError(
                f"translator plugin {self.name!r} ({self.target}, from {self.distribution}) "
                f"failed to import: {reason}"
            ) from None
        if not (isinstance(obj, type) and issubclass(obj, Translator)):
            raise TactileBenchError(
                f"translator plugin {self.name!r} ({self.target}) is not a Translator subclass"
            )
        if obj.name != self.name:
            raise TactileBenchError(
                f"translator plugin {self.name!r} ({self.target}) declares name {obj.name!r}"
            )
        return obj


def discover() -> dict[str, TranslatorEntry]:
    """All registered translators by name; duplicate names with different targets are an error."""
    found: dict[str, TranslatorEntry] = {}
    for ep in entry_points(group=GROUP):
        dist = ep.dist.name if ep.dist is not None else "?"
        entry = TranslatorEntry(ep.name, ep.value, dist)
        previous = found.get(ep.name)
        if previous is not None and previous.target != entry.target:
            raise TactileBenchError(
                f"translator name {ep.name!r} is registered twice: {previous.target} "
                f"({previous.distribution}) and {entry.target} ({dist})"
            )
        found[ep.name] = entry
    return dict(sorted(found.items()))


def translator_class(name: str) -> type[Translator]:
    """The class registered under ``name``."""
    registry = discover()
    if name not in registry:
        known = ", ".join(registry) or "none"
        raise TactileBenchError(f"unknown translator {name!r} (registered: {known})")
    return registry[name].load()


def create_translator(
    name: str, config: TranslatorConfig | dict[str, Any] | None = None
) -> Translator:
    """Construct a registered translator from its (validated) config."""
    return translator_class(name)(config)


def load_checkpoint(path: str | Path) -> Translator:
    """Load a translator checkpoint of any registered translator (the file says which)."""
    path = Path(path)
    require_not_special(path, "translator checkpoint")  # a FIFO would block torch.load
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        name = payload["translator"]
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: translator checkpoint not found") from None
    except Exception:  # unreadable or foreign: let the class loader word the error
        return _Unknown.load(path)  # raises the one-line error that fits the file
    if not isinstance(name, str):
        raise TactileBenchError(f"{path}: not a tactile_bench translator checkpoint")
    try:
        kind = translator_class(name)
    except TactileBenchError as exc:
        raise TactileBenchError(f"{path}: {exc}") from None
    return kind.load(path)


class _Unknown(Translator):
    """Stands in for "some translator" so ``Translator.load`` words errors of unreadable files."""

    name = "?"
