"""Our log lines on stderr, set up the same way by the command line and by the runner's
worker processes (``pipeline.side_by_side``), so a stage logs alike wherever it runs."""

from __future__ import annotations

import logging
import sys
from typing import Any


class _CurrentStderr(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time (tests and notebooks swap it; a
    handler bound to the first one would write to a closed stream)."""

    @property
    def stream(self) -> Any:  # type: ignore[override]
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def configure_logging(level: int) -> None:
    """Our own messages on stderr; Lightning keeps its own handler (no duplicated lines)."""
    logger = logging.getLogger("tactile_bench")
    logger.setLevel(level)
    if not logger.handlers:
        handler = _CurrentStderr()
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        logger.addHandler(handler)
        logger.propagate = False
