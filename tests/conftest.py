"""Shared fixtures: offline logging, no progress-bar noise, a repo-root path."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import torch

from tactile_bench.bench.report import render_markdown
from tactile_bench.testing import available_devices

REPO = Path(__file__).resolve().parents[1]

os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")


@pytest.fixture(autouse=True, scope="session")
def one_torch_thread() -> Iterator[None]:
    """Tests use tiny tensors: one thread is as fast on an idle machine and 10-100x faster
    on a busy one (two threads contend for the core another process holds)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def repo() -> Path:
    """The repository root (recipes/, plugins/)."""
    return REPO


@pytest.fixture(params=available_devices())
def device(request: pytest.FixtureRequest) -> torch.device:
    """Each device this machine has: the CPU always, CUDA where there is a GPU (a test
    that takes it runs once a device)."""
    return torch.device(request.param)


def _bench_markdown(**sections: Any) -> str:
    machine = {
        "cpu": "test cpu",
        "cpu_capability": "AVX512",
        "cores": 2,
        "torch": torch.__version__,
        "torch_threads": 1,
        "diffusers": "-",
        "lightning": "-",
        "python": "3",
        "ld_preload": "",
        **sections.pop("machine", {}),
    }
    result = {"machine": machine, "config": {"quick": True}, "wall_s": 1.0}
    result |= {"loadavg_start": [0, 0, 0], "loadavg_end": [0, 0, 0]}
    return render_markdown(result | sections)


@pytest.fixture
def bench_markdown() -> Callable[..., str]:
    """``bench.report.render_markdown`` of a result that holds only the given sections beside
    a minimal machine record (a ``machine`` section adds to or overrides its keys)."""
    return _bench_markdown
