"""The project's own error type: every user-facing failure is one line, not a traceback."""

from __future__ import annotations


class TactileBenchError(Exception):
    """A problem with the user's input or environment, reported as one line by the CLI.

    Raise it with a message that names the file (and key) at fault, e.g.
    ``TactileBenchError("recipes/x.yaml: stages.train.epochs: must be an integer")``.
    """
