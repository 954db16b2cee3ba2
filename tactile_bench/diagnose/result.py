"""The diagnosis's answer as types: what ``run.diagnose`` returns and report.json holds."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import tactile_bench
from tactile_bench.diagnose.shrink import HowFar
from tactile_bench.diagnose.where import WhereResult
from tactile_bench.diagnose.which import WhichResult


@dataclass(frozen=True)
class Split:
    """How the pairs were split into the fit and held-out halves."""

    n_fit: int
    n_held: int
    fit_fraction: float
    seed: int
    stratified_by: str = "label"


@dataclass(frozen=True)
class Sample:
    """A held-out pair shown in the before/after figure."""

    index: int
    label: str
    name: str


#: report.json's "which" keeps what the "which" step reports beyond these top-level keys
_WHICH_TOP = (
    "ranking",
    "singles",
    "unexplained",
    "residual_flagged",
    "stability",
    "unstable",
    "flagged",
    "gap_metric",
    "background",
    "background_note",
    "shapley",
)


@dataclass
class Diagnosis:
    """The whole answer: where the gap lies, which effects explain it, how far it shrinks."""

    n_pairs: int
    size: int
    input: dict[str, Any]  # the source (root, layout, ...) and the pairs' content hash
    split: Split
    where: WhereResult
    where_held: tuple[WhereResult, WhereResult] | None  # held-out, before / after effects
    which: WhichResult
    how_far: HowFar
    samples: list[Sample]
    timing_s: dict[str, Any] = field(default_factory=dict)  # seconds; "breakdown": spans
    version: str = tactile_bench.__version__

    def to_dict(self) -> dict[str, Any]:
        """report.json's content."""
        which = self.which.to_dict()
        far = self.how_far.to_dict()
        return {
            "version": self.version,
            "n_pairs": self.n_pairs,
            "size": self.size,
            "input": self.input,
            "split": asdict(self.split),
            "where": self.where.summary,
            "where_held": None
            if self.where_held is None
            else {"before": self.where_held[0].summary, "after": self.where_held[1].summary},
            "gap_metric": which["gap_metric"],
            "background": which["background"],
            "background_note": which["background_note"],
            "ranking": which["ranking"],
            "shapley": which["shapley"],
            "singles": which["singles"],
            "unexplained": which["unexplained"],
            "residual_flagged": which["residual_flagged"],
            "stability": which["stability"],
            "flagged": which["flagged"],
            "which": {k: v for k, v in which.items() if k not in _WHICH_TOP},
            "how_far": far,
            "downstream": far["downstream"],
            "samples": [asdict(s) for s in self.samples],
            "timing_s": self.timing_s,
        }
