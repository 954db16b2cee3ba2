"""The kinds of rule a command argument follows, and the bounds they share.

A rule checks a value alone (a count in range, a seed, a finite number, a list without
duplicates, a YAML file the safe loader reads); which argument of which command follows
which rule is the command line's own table (``tactile_bench.cli_args``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.limits import check_int, check_seed, check_unique
from tactile_bench.guard.safe_yaml import load_yaml_file

#: the largest count any argument takes (pairs, steps, images, repetitions)
MAX_COUNT = 10_000_000
#: image sides: the models' smallest, and the largest frame a reader decodes
MIN_SIZE, MAX_SIZE = 16, 4096
#: bytes a (depth, sim, real) pair of S x S pixels takes per pixel: stored (float32 depth,
#: uint8 images) plus the float copies the diagnosis and its fits hold
BYTES_PER_PAIR_PIXEL = 4 + 3 + 3 + 4 * 7
#: bytes per pixel a pair takes on disk (16-bit depth, two RGB PNGs, before compression)
DISK_PER_PAIR_PIXEL = 2 + 3 + 3


def flag(dest: str) -> str:
    """``--max-pairs`` for ``max_pairs``."""
    return "--" + dest.replace("_", "-")


@dataclass(frozen=True)
class Count:
    """A whole number in ``[low, high]``; 0 is never a stand-in for "the default"."""

    low: int = 1
    high: int = MAX_COUNT

    def __call__(self, dest: str, value: object) -> None:
        check_int(flag(dest), value, self.low, self.high)


@dataclass(frozen=True)
class Seed:
    """A seed: 0 .. 2**32 - 1."""

    def __call__(self, dest: str, value: object) -> None:
        check_seed(flag(dest), value)


@dataclass(frozen=True)
class Real:
    """A finite number in ``low < x < high`` (``closed_high``: ``x <= high``; ``closed_low``:
    ``low <= x``)."""

    low: float
    high: float
    closed_high: bool = False
    unit: str = ""
    closed_low: bool = False

    def __call__(self, dest: str, value: object) -> None:
        x = float(value)  # type: ignore[arg-type]
        above = x > self.high if self.closed_high else x >= self.high
        below = x < self.low if self.closed_low else x <= self.low
        if not math.isfinite(x) or below or above:
            bracket = "]" if self.closed_high else ")"
            opening = "[" if self.closed_low else "("
            raise TactileBenchError(
                f"{flag(dest)}: must be in {opening}{self.low:g}, {self.high:g}{bracket}"
                f"{' ' + self.unit if self.unit else ''}, got {value}"
            )


@dataclass(frozen=True)
class Names:
    """A list of names (or a string of characters): no duplicates; ``nonempty`` if given."""

    nonempty: bool = True

    def __call__(self, dest: str, value: object) -> None:
        if self.nonempty and isinstance(value, (list, tuple, str)) and len(value) == 0:
            raise TactileBenchError(f"{flag(dest)}: give at least one, or leave it out")
        check_unique(flag(dest), value)


@dataclass(frozen=True)
class Text:
    """A string of at most ``max_len`` characters (a word to render, not a book)."""

    max_len: int

    def __call__(self, dest: str, value: object) -> None:
        if isinstance(value, str) and len(value) > self.max_len:
            raise TactileBenchError(
                f"{flag(dest)}: {len(value)} characters; at most {self.max_len}"
            )


@dataclass(frozen=True)
class YamlFile:
    """A recipe or profile path, read now by the safe loader (regular file, no alias bomb,
    no key twice): refused before the command imports its machinery. ``named`` allows a
    built-in name instead of a path (a profile name has no suffix)."""

    what: str
    named: bool = False

    def __call__(self, dest: str, value: object) -> None:
        if isinstance(value, str) and not (self.named and not Path(value).suffix):
            load_yaml_file(value, self.what)


Rule = Callable[[str, object], None]


@dataclass(frozen=True)
class Output:
    """An output argument: a folder or a file (with the suffixes its format has), locked
    while the command runs unless ``lock`` is False."""

    folder: bool
    suffixes: tuple[str, ...] = ()
    lock: bool = True
