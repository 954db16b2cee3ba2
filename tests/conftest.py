"""Shared fixtures: offline logging, no progress-bar noise, a repo-root path."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")


@pytest.fixture
def repo() -> Path:
    """The repository root (recipes/, plugins/)."""
    return REPO
