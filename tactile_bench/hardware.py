"""What this machine computes fast: the one place that picks a training / sampling precision.

bf16 autocast is a speed-up only where the hardware has bf16 arithmetic. On an AVX2 CPU
(no AVX-512-BF16, no AMX) oneDNN emulates it and a convolution runs many times slower than
in fp32; on AVX-512-BF16 or AMX CPUs it is faster (docs/results/precision.md). So
``precision: auto`` (the default of every config that chooses one) resolves per machine:
bf16 where it is native, fp32 elsewhere. "Native" also means oneDNN may use it:
``ONEDNN_MAX_CPU_ISA`` capped below AVX512_CORE_BF16 makes an AVX-512-BF16 CPU run bf16
convolutions as an AVX2 one does, so ``auto`` then picks fp32 as it would there.

Lowest layer: imports torch and the standard library only.
"""

from __future__ import annotations

import functools
import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import torch

log = logging.getLogger("tactile_bench")

#: what a config may ask for; "auto" is resolved by :func:`resolve_precision`
Precision = Literal["auto", "32-true", "bf16-mixed"]
PRECISIONS: tuple[str, ...] = ("auto", "32-true", "bf16-mixed")
_CPUINFO_FLAGS = ("avx512_bf16", "amx_bf16")
#: oneDNN ISA caps (``ONEDNN_MAX_CPU_ISA``, oneDNN's docs "CPU dispatcher control") with no
#: bf16 dot product: under them oneDNN emulates bf16 whatever the CPU has
_ONEDNN_CAPS_WITHOUT_BF16 = frozenset(
    {"SSE41", "AVX", "AVX2", "AVX2_VNNI", "AVX2_VNNI_2", "AVX512_CORE", "AVX512_CORE_VNNI"}
)
_ONEDNN_CAP_VARIABLES = ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA")  # the second: its old name
#: environment variables that cap the instruction sets torch's kernels use on this CPU
ISA_CAP_VARIABLES = ("ATEN_CPU_CAPABILITY", *_ONEDNN_CAP_VARIABLES)
_WARNED: set[str] = set()  # devices already warned about a slow explicit bf16


def _onednn_allows_bf16() -> bool:
    """False when ``ONEDNN_MAX_CPU_ISA`` (or its old name ``DNNL_MAX_CPU_ISA``) caps oneDNN
    below bf16 arithmetic, e.g. to reproduce an AVX2 machine's kernels on a newer CPU."""
    for name in _ONEDNN_CAP_VARIABLES:
        cap = os.environ.get(name)
        if cap:
            return cap.strip().upper() not in _ONEDNN_CAPS_WITHOUT_BF16
    return True


@functools.cache
def cpu_native_bf16() -> bool:
    """AVX-512-BF16 or AMX that oneDNN may use: torch's own probes when it has them, else
    /proc/cpuinfo; and no ``ONEDNN_MAX_CPU_ISA`` cap below bf16."""
    if not _onednn_allows_bf16():
        return False
    probes = [
        getattr(torch.cpu, name, None)
        for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    ]
    probes = [p for p in probes if callable(p)]
    if probes:
        return any(bool(p()) for p in probes)
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    flags = set(text.split())
    return any(flag in flags for flag in _CPUINFO_FLAGS)


def native_bf16(device: str = "cpu") -> bool:
    """Whether ``device`` ("cpu", "cuda", ...) has bf16 arithmetic, so autocast pays off."""
    kind = device.split(":")[0]
    if kind == "cpu":
        return cpu_native_bf16()
    if kind == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    return False


def trainer_device(accelerator: Any = None) -> str:
    """The device kind a Lightning ``accelerator`` setting (None: Lightning's "auto") runs on."""
    if accelerator is None or accelerator == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    name = (accelerator if isinstance(accelerator, str) else type(accelerator).__name__).lower()
    if name in ("gpu", "cuda") or "cuda" in name:
        return "cuda"
    return "mps" if "mps" in name else "cpu"


def compute_device(accelerator: Any = None) -> torch.device:
    """Where a stage's networks run for a Lightning ``accelerator`` setting (None / "auto":
    the GPU when there is one): fits follow the Trainer, and translation, evaluation and the
    other work outside a Trainer follows this."""
    return torch.device(trainer_device(accelerator))


def use_tensor_cores() -> None:
    """fp32 matrix products on a CUDA GPU's tensor cores (TF32), as Lightning advises: ~2x
    the fp32 speed at a 10-bit mantissa, below what bf16 training already rounds to. No
    effect on the CPU."""
    if torch.cuda.is_available():
        torch.set_float32_matmul_precision("high")


def describe_device(device: torch.device) -> str:
    """A device as a log line names it: ``cpu`` or ``cuda:0 (NVIDIA H100 80GB HBM3)``."""
    if device.type == "cuda" and torch.cuda.is_available():
        index = device.index if device.index is not None else torch.cuda.current_device()
        return f"cuda:{index} ({torch.cuda.get_device_name(index)})"
    return device.type


def conv_slowdown() -> float:
    """bf16-autocast time over fp32 time of a tiny 3 x 3 conv (well under 0.2 s on AVX2)."""
    gen = torch.Generator().manual_seed(0)  # own generator: the global RNG stays untouched
    x = torch.randn(4, 16, 32, 32, generator=gen)
    weight, bias = torch.randn(16, 16, 3, 3, generator=gen) / 12, torch.zeros(16)

    def conv(x: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(x, weight, bias, padding=1)

    def fastest(bf16: bool) -> float:
        times = []
        with torch.no_grad(), torch.autocast("cpu", torch.bfloat16, enabled=bf16):
            for _ in range(4):  # the first is a warm-up: oneDNN picks its kernels
                start = time.perf_counter()
                conv(x)
                times.append(time.perf_counter() - start)
        return min(times[1:])

    # One thread: the question is the core's arithmetic, and on a busy machine a second
    # thread waits for the other core (measured: 32 ms for this 0.5 ms conv).
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return fastest(True) / max(fastest(False), 1e-9)
    finally:
        torch.set_num_threads(threads)


def _warn_slow_bf16(device: str) -> None:
    """Warn once per process and device that an explicit bf16 runs emulated here."""
    kind = device.split(":")[0]
    if kind in _WARNED:
        return
    _WARNED.add(kind)
    if kind == "cpu":
        capability = torch.backends.cpu.get_cpu_capability()
        why = f"a 3x3 conv ran {conv_slowdown():.0f}x slower than fp32 here"
        where = f"a CPU without native bf16 ({capability})"
    else:
        why, where = "expect it to be slower than fp32", f"{kind} without native bf16"
    log.warning("bf16 requested on %s: %s; use precision: auto", where, why)


def resolve_precision(requested: str, device: str = "cpu") -> str:
    """``"auto"`` -> ``"bf16-mixed"`` where ``device`` has native bf16, else ``"32-true"``.

    ``"32-true"`` and ``"bf16-mixed"`` pass through; an explicit bf16 on a device without
    native bf16 still runs, with a warning (once a process) saying how much slower it is.
    """
    if requested not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}; got {requested!r}")
    native = native_bf16(device)
    if requested == "auto":
        return "bf16-mixed" if native else "32-true"
    if requested == "bf16-mixed" and not native:
        _warn_slow_bf16(device)
    return requested


def trainer_precision(settings: Mapping[str, Any], configured: str) -> Any:
    """The ``precision`` a Lightning Trainer gets: the trainer settings' own when they set one
    (resolved if it is one of ours, e.g. ``auto``; any other Lightning value passes as is),
    else the config's ``configured`` precision, resolved for the settings' accelerator."""
    device = trainer_device(settings.get("accelerator"))
    explicit = settings.get("precision")
    if explicit is None:
        return resolve_precision(configured, device)
    return resolve_precision(explicit, device) if explicit in PRECISIONS else explicit


def isa_caps() -> dict[str, str]:
    """The ISA caps set in this process's environment: a run under them times another CPU's
    kernels on this one, which its record must say."""
    return {name: os.environ[name] for name in ISA_CAP_VARIABLES if os.environ.get(name)}


def machine_compute() -> dict[str, Any]:
    """What precision and speed figures depend on: for run.json, reports and the bench."""
    gpu = torch.cuda.is_available()
    return {
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "native_bf16": native_bf16("cpu"),
        "torch_threads": torch.get_num_threads(),
        "auto_precision": resolve_precision("auto"),
        "isa_caps": isa_caps(),
        "gpu": describe_device(torch.device("cuda")) if gpu else None,
        "gpu_auto_precision": resolve_precision("auto", "cuda") if gpu else None,
    }
