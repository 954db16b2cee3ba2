"""``precision: auto``: bf16 only where the hardware has it; explicit bf16 elsewhere warns once."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from tactile_bench import hardware


@pytest.fixture
def probes(monkeypatch: pytest.MonkeyPatch) -> Any:
    """Set torch's CPU bf16 probes (the real cached answer is restored afterwards), on a
    machine without a GPU (``auto`` would pick CUDA's precision where there is one)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)

    def set_probes(avx512_bf16: bool, amx: bool) -> None:
        monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16)
        monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
        hardware.cpu_native_bf16.cache_clear()

    yield set_probes
    hardware.cpu_native_bf16.cache_clear()


@pytest.fixture
def warnings_seen(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Messages hardware logs as warnings, with the once-a-process memory reset."""
    seen: list[str] = []
    monkeypatch.setattr(hardware, "_WARNED", set())
    monkeypatch.setattr(hardware.log, "warning", lambda msg, *args: seen.append(msg % args))
    return seen


def test_torch_has_the_probes_we_use() -> None:
    assert hasattr(torch.cpu, "_is_avx512_bf16_supported")
    assert hasattr(torch.cpu, "_is_amx_tile_supported")


@pytest.mark.parametrize(
    ("avx512_bf16", "amx", "native"),
    [(False, False, False), (True, False, True), (False, True, True), (True, True, True)],
)
def test_native_bf16_from_torch_probes(
    probes: Any, avx512_bf16: bool, amx: bool, native: bool
) -> None:
    probes(avx512_bf16, amx)
    assert hardware.native_bf16("cpu") is native
    assert hardware.resolve_precision("auto") == ("bf16-mixed" if native else "32-true")


@pytest.mark.parametrize(
    ("variable", "cap", "native"),
    [
        ("ONEDNN_MAX_CPU_ISA", "AVX2", False),
        ("ONEDNN_MAX_CPU_ISA", "avx512_core", False),
        ("DNNL_MAX_CPU_ISA", "AVX512_CORE_VNNI", False),
        ("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_BF16", True),
        ("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_AMX", True),
        ("ONEDNN_MAX_CPU_ISA", "ALL", True),
    ],
)
def test_a_onednn_isa_cap_below_bf16_means_fp32(
    probes: Any, monkeypatch: pytest.MonkeyPatch, variable: str, cap: str, native: bool
) -> None:
    """An AVX-512-BF16 CPU whose oneDNN is capped to AVX2 emulates bf16 as an AVX2 CPU does."""
    for name in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv(variable, cap)
    probes(True, False)
    assert hardware.native_bf16("cpu") is native
    assert hardware.resolve_precision("auto") == ("bf16-mixed" if native else "32-true")


def test_cpuinfo_fallback_without_torch_probes(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"):
        monkeypatch.delattr(torch.cpu, name)
    text = {"flags": "fpu sse avx2 fma"}

    class FakePath:
        def __init__(self, path: str) -> None:
            assert path == "/proc/cpuinfo"

        def read_text(self) -> str:
            return f"processor : 0\nflags\t\t: {text['flags']}\n"

    monkeypatch.setattr(hardware, "Path", FakePath)
    hardware.cpu_native_bf16.cache_clear()
    try:
        assert not hardware.native_bf16()
        text["flags"] = "fpu avx2 avx512f avx512_bf16"
        hardware.cpu_native_bf16.cache_clear()
        assert hardware.native_bf16()
        text["flags"] = "fpu avx2 amx_bf16 amx_tile"
        hardware.cpu_native_bf16.cache_clear()
        assert hardware.native_bf16()
    finally:
        hardware.cpu_native_bf16.cache_clear()


def test_no_cuda_means_no_cuda_bf16() -> None:
    if torch.cuda.is_available():
        pytest.skip("a CUDA machine: the answer is the GPU's")
    assert not hardware.native_bf16("cuda")
    assert hardware.resolve_precision("auto", "cuda") == "32-true"
    assert hardware.resolve_precision("auto", "mps") == "32-true"


def test_explicit_precisions_pass_through(probes: Any, warnings_seen: list[str]) -> None:
    probes(True, True)
    assert hardware.resolve_precision("32-true") == "32-true"
    assert hardware.resolve_precision("bf16-mixed") == "bf16-mixed"
    assert warnings_seen == []  # native bf16: nothing to warn about
    probes(False, False)
    assert hardware.resolve_precision("32-true") == "32-true"
    assert warnings_seen == []


def test_explicit_bf16_without_native_warns_once_with_a_measurement(
    probes: Any, warnings_seen: list[str]
) -> None:
    probes(False, False)
    for _ in range(3):
        assert hardware.resolve_precision("bf16-mixed") == "bf16-mixed"
    assert len(warnings_seen) == 1
    message = warnings_seen[0]
    assert "without native bf16" in message and "precision: auto" in message
    assert torch.backends.cpu.get_cpu_capability() in message
    assert "3x3 conv ran" in message and "x slower than fp32" in message


def test_the_warning_measurement_is_quick_and_keeps_global_state() -> None:
    import time

    state, threads = torch.get_rng_state(), torch.get_num_threads()
    start = time.perf_counter()
    ratio = hardware.conv_slowdown()
    assert time.perf_counter() - start < 1.0  # ~0.1 s on a 2-core AVX2 machine
    assert ratio > 0
    if not hardware.native_bf16():
        assert ratio > 2  # emulated bf16: 20-50x on an AVX2 core
    assert torch.equal(torch.get_rng_state(), state)
    assert torch.get_num_threads() == threads


@pytest.mark.parametrize("bad", ["bf16", "fp32", "16-mixed", "", "AUTO"])
def test_unknown_precisions_are_errors(bad: str) -> None:
    with pytest.raises(ValueError, match="precision must be one of"):
        hardware.resolve_precision(bad)


def test_trainer_precision_prefers_the_trainer_settings(probes: Any) -> None:
    probes(False, False)
    assert hardware.trainer_precision({}, "auto") == "32-true"
    assert hardware.trainer_precision({"accelerator": "cpu"}, "32-true") == "32-true"
    assert hardware.trainer_precision({"precision": "auto"}, "bf16-mixed") == "32-true"
    assert hardware.trainer_precision({"precision": "16-mixed"}, "auto") == "16-mixed"
    assert hardware.trainer_precision({"precision": 32}, "auto") == 32
    probes(True, False)
    assert hardware.trainer_precision({}, "auto") == "bf16-mixed"


def test_trainer_device() -> None:
    assert hardware.trainer_device("cpu") == "cpu"
    assert hardware.trainer_device("gpu") == "cuda"
    assert hardware.trainer_device("cuda") == "cuda"
    assert hardware.trainer_device(None) == ("cuda" if torch.cuda.is_available() else "cpu")


def test_machine_compute(probes: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    for name in hardware.ISA_CAP_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    probes(False, False)
    info = hardware.machine_compute()
    assert info == {
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "native_bf16": False,
        "torch_threads": torch.get_num_threads(),
        "auto_precision": "32-true",
        "isa_caps": {},
        "gpu": None,
        "gpu_auto_precision": None,
    }
    probes(False, True)
    assert hardware.machine_compute()["auto_precision"] == "bf16-mixed"


def test_a_run_under_isa_caps_says_so(probes: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """Timings under ATEN_CPU_CAPABILITY / ONEDNN_MAX_CPU_ISA are another CPU's kernels on
    this one: run.json and the report's machine line carry the caps."""
    from tactile_bench.pipeline.stages.report import machine_line

    for name in hardware.ISA_CAP_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    probes(True, False)
    assert "capped" not in machine_line(hardware.machine_compute())
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    hardware.cpu_native_bf16.cache_clear()
    info = hardware.machine_compute()
    assert info["isa_caps"] == {"ONEDNN_MAX_CPU_ISA": "AVX2"}
    assert info["auto_precision"] == "32-true"
    assert machine_line(info).endswith("(instruction sets capped: ONEDNN_MAX_CPU_ISA=AVX2)")


def test_compute_device_and_gpu_precision(monkeypatch: pytest.MonkeyPatch) -> None:
    """``auto`` means the GPU when there is one, for fits and for the work around them."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda: True)
    assert hardware.compute_device(None) == torch.device("cuda")
    assert hardware.compute_device("auto") == torch.device("cuda")
    assert hardware.compute_device("cpu") == torch.device("cpu")
    assert hardware.trainer_precision({}, "auto") == "bf16-mixed"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert hardware.compute_device(None) == torch.device("cpu")
