"""tactile_bench.allocator: glibc keeps freed tensor memory; the CLI and the bench use it.

The speed it buys is measured by the bench (braille contacts/s), not asserted here.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from tactile_bench import allocator
from tactile_bench.cli import main

needs_glibc = pytest.mark.skipif(allocator.glibc() is None, reason="malloc is not glibc's")

# A fresh process makes and frees one 8 MB tensor; glibc's mallinfo2 says whether the
# block had its own mapping and how much freed memory the heap kept.
_ONE_TENSOR = """
import ctypes, sys, torch
from tactile_bench import allocator
class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "tuned":
    assert allocator.keep_freed_memory()
before = libc.mallinfo2().hblkhd
x = torch.empty(2 << 20).fill_(1.0)
mapped = libc.mallinfo2().hblkhd - before
del x
print(mapped >> 20, libc.mallinfo2().fordblks >> 20)
"""


def _one_tensor(mode: str) -> tuple[int, int]:
    cmd = [sys.executable, "-c", _ONE_TENSOR, mode]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.split()
    return int(out[0]), int(out[1])


@needs_glibc
def test_a_freed_tensor_stays_in_the_heap_for_the_next_one() -> None:
    mapped, kept = _one_tensor("default")
    assert mapped >= 8 and kept < 8  # glibc's default: own mapping, unmapped when freed
    mapped, kept = _one_tensor("tuned")
    assert mapped == 0 and kept >= 8  # from the heap, and still there once freed


@needs_glibc
def test_the_command_line_sets_it_and_the_bench_reports_it() -> None:
    from tactile_bench.bench.run import machine_info

    assert main(["list"]) == 0
    assert machine_info()["malloc"] == "glibc, mmap threshold 32 MiB, trim threshold 128 MiB"
