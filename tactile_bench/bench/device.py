"""``bench --device cuda``: sampling and training rows on an accelerator beside the CPU's.

Each row runs the same work on every device asked for (the CPU always): diffusion sampling
(the fast sampler the tables use, and DDPM-500 on a few images), training steps of the
diffusion translator, the cGAN and the braille classifier. A row gives images/s, the
device's peak memory and, on a GPU, the share of ``nvidia-smi`` samples (every 0.2 s) that
found it busy. Timings wait for the device (``synchronize``) before the clock stops.
"""

from __future__ import annotations

import shutil
import statistics
import subprocess
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import torch

from tactile_bench.bench.timing import polling
from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.data.synthetic import tiny_pairs
from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import describe_device, resolve_precision
from tactile_bench.translators import create_translator

#: (row name, translator config) of the sampling rows: the tables' sampler and the paper's
SAMPLING_ROWS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("dpmsolver++ 2 steps", {"sampler": "dpmsolver++", "steps": 2}),
    ("ddpm 500 steps", {"sampler": "ddpm", "steps": 500}),
)


@dataclass
class DeviceBenchSizes:
    """How much work a row does; ``quick`` is the CLI's ``--quick``."""

    presets: tuple[str, ...] = ("cpu-small", "paper")
    sample_images: int = 256
    ddpm_images: int = 16
    train_batch: int = 32
    train_steps: int = 20
    classifier_batch: int = 256
    repeats: int = 3
    image_size: int = 64
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def quick(cls) -> DeviceBenchSizes:
        return cls(
            presets=("cpu-small",),
            sample_images=32,
            ddpm_images=2,
            train_steps=4,
            classifier_batch=64,
            repeats=1,
        )


def check_device(name: str) -> torch.device:
    """The device ``--device`` names, or a one-line error when this machine has none."""
    try:
        device = torch.device(name)
    except RuntimeError:
        raise TactileBenchError(
            f"bench --device {name!r}: not a device (cpu, cuda, cuda:1)"
        ) from None
    if device.type not in ("cpu", "cuda"):
        raise TactileBenchError(f"bench --device {name}: only cpu and cuda are measured")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise TactileBenchError("bench --device cuda: torch sees no CUDA device on this machine")
    return device


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@contextmanager
def gpu_busy(device: torch.device, period_s: float = 0.2) -> Iterator[dict[str, Any]]:
    """Samples the GPU's utilisation with ``nvidia-smi`` while the block runs; the dict
    gets ``busy_share`` (samples above 0 %) and ``samples``, or None off a GPU."""
    found: dict[str, Any] = {"busy_share": None, "samples": 0}
    smi = shutil.which("nvidia-smi")
    if device.type != "cuda" or smi is None:
        yield found
        return
    index = device.index if device.index is not None else torch.cuda.current_device()
    readings: list[float] = []
    query = [smi, f"--id={index}", "--query-gpu=utilization.gpu", "--format=csv,noheader"]

    def poll() -> None:
        out = subprocess.run(query, capture_output=True, text=True, check=False).stdout
        value = out.strip().rstrip("%").strip()
        if value.isdigit():
            readings.append(float(value))

    try:
        with polling(poll, period_s):
            yield found
    finally:
        found["samples"] = len(readings)
        found["busy_share"] = sum(r > 0 for r in readings) / len(readings) if readings else None


def _timed(device: torch.device, repeats: int, run: Callable[[], None]) -> dict[str, Any]:
    """Median wall time of ``run`` after one warm-up, peak device memory, GPU busy share."""
    run()
    _sync(device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    times = []
    with gpu_busy(device) as busy:
        for _ in range(repeats):
            start = time.perf_counter()
            run()
            _sync(device)
            times.append(time.perf_counter() - start)
    peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else None
    return {"median_s": statistics.median(times), "peak_mib": peak, **busy}


def _sampling_row(
    device: torch.device, preset: str, name: str, settings: dict[str, Any], n: int, repeats: int
) -> dict[str, Any]:
    size = 64
    translator = create_translator("diffusion", {"preset": preset, **settings}).to(device).eval()
    depth, _ = tiny_pairs(n=n, size=size, seed=1)
    depth = depth.to(device)

    def run() -> None:
        translator.translate_foreground(depth, torch.Generator().manual_seed(0))

    timing = _timed(device, repeats, run)
    return {"row": f"sample {preset} {name}", "images": n, **timing}


def _train_row(
    device: torch.device,
    name: str,
    module: torch.nn.Module,
    step: Callable[[], torch.Tensor],
    batch: int,
    steps: int,
    repeats: int,
) -> dict[str, Any]:
    optimiser = torch.optim.Adam(module.parameters(), lr=1e-4)
    precision = resolve_precision("auto", device.type)

    def run() -> None:
        warnings.filterwarnings("ignore", message="You are trying to `self.log()`")
        for _ in range(steps):
            optimiser.zero_grad(set_to_none=True)
            with torch.autocast(device.type, torch.bfloat16, enabled=precision == "bf16-mixed"):
                loss = step()
            loss.backward()
            optimiser.step()

    timing = _timed(device, repeats, run)
    return {"row": f"train {name}", "images": batch * steps, "precision": precision, **timing}


def _training_rows(device: torch.device, sizes: DeviceBenchSizes) -> list[dict[str, Any]]:
    rows = []
    depth, fg = tiny_pairs(n=sizes.train_batch, size=sizes.image_size, seed=2)
    depth, fg = depth.to(device), fg.to(device)
    for preset in sizes.presets:
        diffusion = create_translator("diffusion", {"preset": preset}).to(device).train()
        rows.append(
            _train_row(
                device,
                f"diffusion {preset}",
                diffusion,
                lambda d=diffusion: d.training_step((depth, fg), 0),
                sizes.train_batch,
                sizes.train_steps,
                sizes.repeats,
            )
        )
    classifier = BrailleClassifier().to(device).train()
    x = fg[:1].expand(sizes.classifier_batch, -1, -1, -1).contiguous()
    labels = torch.zeros(sizes.classifier_batch, dtype=torch.long, device=device)
    rows.append(
        _train_row(
            device,
            "classifier",
            classifier,
            lambda: torch.nn.functional.cross_entropy(classifier(x), labels),
            sizes.classifier_batch,
            sizes.train_steps,
            sizes.repeats,
        )
    )
    return rows


def device_rows(devices: list[torch.device], sizes: DeviceBenchSizes) -> dict[str, Any]:
    """Every row on every device in ``devices``, side by side, with the ratio to the CPU."""
    table: dict[str, dict[str, Any]] = {}
    for device in devices:
        rows = [
            _sampling_row(
                device,
                preset,
                name,
                settings,
                sizes.ddpm_images if settings["steps"] > 100 else sizes.sample_images,
                sizes.repeats,
            )
            for preset in sizes.presets
            for name, settings in SAMPLING_ROWS
        ]
        rows += _training_rows(device, sizes)
        for row in rows:
            row["images_per_s"] = row["images"] / row["median_s"]
            table.setdefault(row["row"], {})[describe_device(device)] = row
    cpu = describe_device(torch.device("cpu"))
    for by_device in table.values():
        base = by_device.get(cpu, {}).get("images_per_s")
        for row in by_device.values():
            row["speedup_vs_cpu"] = row["images_per_s"] / base if base else None
    return {"devices": [describe_device(d) for d in devices], "rows": table}


def _or_dash(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def device_markdown(section: dict[str, Any]) -> list[str]:
    """bench.md's lines for the device section: one table, a row a measurement a device."""
    lines = ["## Sampling and training on each device", ""]
    lines += [
        "| row | device | images/s | x CPU | peak device MiB | GPU busy |",
        "|" + " --- |" * 6,
    ]
    for name, by_device in section["rows"].items():
        for device, row in by_device.items():
            busy = row["busy_share"]
            busy_text = "-" if busy is None else f"{100 * busy:.0f}% of {row['samples']} samples"
            lines.append(
                f"| {name} | {device} | {row['images_per_s']:.1f} | "
                f"{_or_dash(row['speedup_vs_cpu'], '.1f')} | {_or_dash(row['peak_mib'], '.0f')} "
                f"| {busy_text} |"
            )
    return [*lines, ""]
