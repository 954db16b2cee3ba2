"""Random draws from an effect's generator, and replaying them without rendering.

``randn`` is the one normal draw the effects take; ``replay_draws`` advances a generator
past the draws an ``Effect.draws`` list names, so a stream of batches can be split over
threads (``SurrogateDigit.skip_random``). These concern the generator's position, not any
image kernel, so they are a module of their own rather than part of ``effects.kernels``;
the ``Draw`` type they read stays with ``Effect.draws`` in ``base``.
"""

from __future__ import annotations

import math

import torch

from tactile_bench.effects.base import Draw


def randn(shape: tuple[int, ...], generator: torch.Generator | None) -> torch.Tensor:
    return torch.randn(shape, generator=generator, dtype=torch.float32)


def replay_draws(draws: list[Draw], generator: torch.Generator) -> None:
    """Take ``draws`` from ``generator`` and discard them (see ``Effect.draws``).

    Only the generator's position matters, so the draws are replaced by the cheapest call
    that consumes the same 32-bit words of its Mersenne twister: torch's CPU ``rand``
    takes one word a float32, ``randn`` one a value plus 16 when the count is not a multiple
    of 16 (its Box-Muller works in blocks of 16, recomputing the last block), for 16 values
    or more; fewer go through another algorithm and are drawn for real. The tests compare
    generator states after ``apply`` and after this.
    """
    words = 0
    for kind, shape in draws:
        n = math.prod(shape)
        if kind == "rand":
            words += n
        elif n >= 16:
            words += n + (16 if n % 16 else 0)
        else:
            skip_words(words, generator)
            words = 0
            torch.randn(shape, generator=generator, dtype=torch.float32)
    skip_words(words, generator)


def skip_words(words: int, generator: torch.Generator, block: int = 1 << 20) -> None:
    """Advance ``generator`` by ``words`` 32-bit draws (int32 ``random_`` takes one each)."""
    buffer = torch.empty(min(words, block), dtype=torch.int32)
    for k in range(0, words, block):
        buffer[: min(block, words - k)].random_(generator=generator)
