"""Re-measure the speed figures behind the code's kernel choices (docs/results/code_figures.md).

Each row times the project's kernel against the library call it replaces, on the same input
and one thread, median of ``--repeats`` runs after a warm-up; the two give the same values
(checked here, so a row never compares different work). Run::

    python scripts/code_figures.py [--repeats 30]

The figures are this machine's, at the project's sizes; they say "faster here", not by how
much on another CPU.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from tactile_bench.effects.kernels import area_pool, gaussian_blur
from tactile_bench.sensor.depth import affine_grid


def _median_s(run: Callable[[], object], repeats: int) -> float:
    run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _conv_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """A 1-channel separable Gaussian ``conv2d`` with reflect padding (the replaced call)."""
    radius = int(3 * sigma + 0.5)
    t = torch.arange(-radius, radius + 1, dtype=x.dtype)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    n, c, h, w = x.shape
    y = F.pad(x.reshape(n * c, 1, h, w), (radius, radius, radius, radius), mode="reflect")
    y = F.conv2d(y, k.view(1, 1, 1, -1))
    return F.conv2d(y, k.view(1, 1, -1, 1)).reshape(n, c, h, w)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    repeats = parser.parse_args().repeats
    torch.set_num_threads(1)
    torch.manual_seed(0)
    rows = []

    theta = torch.randn(256, 2, 3)
    torch.testing.assert_close(
        affine_grid(theta, 128),
        F.affine_grid(theta, [256, 1, 128, 128], align_corners=False),
        atol=1e-5,
        rtol=0,
    )
    rows.append(
        (
            "sensor.depth.affine_grid vs F.affine_grid (256 x 128 x 128)",
            _median_s(
                lambda: F.affine_grid(theta, [256, 1, 128, 128], align_corners=False), repeats
            ),
            _median_s(lambda: affine_grid(theta, 128), repeats),
        )
    )

    for shape in ((64, 1, 128, 128), (64, 3, 128, 128)):  # depth's 2x oversampling; images
        x = torch.rand(*shape)
        torch.testing.assert_close(area_pool(x, 2), F.avg_pool2d(x, 2))
        rows.append(
            (
                f"effects.kernels.area_pool vs F.avg_pool2d ({' x '.join(map(str, shape))}, 2 x 2)",
                _median_s(lambda x=x: F.avg_pool2d(x, 2), repeats),
                _median_s(lambda x=x: area_pool(x, 2), repeats),
            )
        )

    sigma = 2.0
    torch.testing.assert_close(
        gaussian_blur(x, torch.tensor(sigma), torch.tensor(sigma)),
        _conv_blur(x, sigma),
        atol=2e-3,
        rtol=0,
    )
    rows.append(
        (
            "effects.kernels.gaussian_blur vs 1-channel conv2d (64 x 3 x 128 x 128, sigma 2 px)",
            _median_s(lambda: _conv_blur(x, sigma), repeats),
            _median_s(lambda: gaussian_blur(x, torch.tensor(sigma), torch.tensor(sigma)), repeats),
        )
    )

    core = (torch.rand(64, 1, 128, 128) > 0.5).float()
    a, b = torch.rand(64, 1, 128, 128), torch.rand(64, 1, 128, 128)
    torch.testing.assert_close(a * core + b * (1 - core), torch.where(core > 0, a, b))
    rows.append(
        (
            "0/1 mask by multiply-add vs torch.where (64 x 1 x 128 x 128)",
            _median_s(lambda: torch.where(core > 0, a, b), repeats),
            _median_s(lambda: a * core + b * (1 - core), repeats),
        )
    )

    print(f"torch {torch.__version__}, 1 thread, median of {repeats}")
    print("| kernel | library call (ms) | ours (ms) | x |")
    print("| --- | --- | --- | --- |")
    for name, theirs, ours in rows:
        print(f"| {name} | {theirs * 1e3:.2f} | {ours * 1e3:.2f} | {theirs / ours:.1f} |")


if __name__ == "__main__":
    main()
