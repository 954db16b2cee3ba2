"""``bench --device``: the sampling and training rows on a device beside the CPU's (issue 39).

Here on the CPU alone (a GPU machine adds its rows beside them); the figures' values are
the machine's, so the tests check what a row holds, not how fast it is."""

from __future__ import annotations

import pytest
import torch

from tactile_bench.bench.device import DeviceBenchSizes, device_markdown, device_rows
from tactile_bench.cli import main

TINY = DeviceBenchSizes(
    presets=("tiny",),
    sample_images=4,
    ddpm_images=1,
    train_batch=4,
    train_steps=2,
    classifier_batch=8,
    repeats=1,
    image_size=32,
)


def test_rows_on_the_cpu_hold_rates_memory_and_busy_share() -> None:
    section = device_rows([torch.device("cpu")], TINY)
    assert section["devices"] == ["cpu"]
    names = set(section["rows"])
    assert {"sample tiny dpmsolver++ 2 steps", "sample tiny ddpm 500 steps"} <= names
    assert {"train diffusion tiny", "train classifier"} <= names
    for by_device in section["rows"].values():
        row = by_device["cpu"]
        assert row["images_per_s"] > 0 and row["speedup_vs_cpu"] == pytest.approx(1.0)
        assert row["peak_mib"] is None and row["busy_share"] is None  # no GPU to read
    table = device_markdown(section)
    assert sum(line.startswith("| train classifier | cpu |") for line in table) == 1


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_asking_for_a_missing_gpu_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--device", "cuda", "--only", "device", "--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: bench --device cuda: torch sees no CUDA device on this machine"]


def test_a_device_that_is_not_one_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--device", "tpu9", "--only", "device"]) == 2
    assert "not a device" in capsys.readouterr().err
