"""The diagnosis's one bootstrap: resampled pair (or window) indices and percentile intervals.

Every interval in the report (shrinks, paired differences, Shapley shares, the no-contact
frame's reading) resamples the same way, so one seed gives one set of draws everywhere.
"""

from __future__ import annotations

import torch

BOOTSTRAP = 500  # resamples per interval


def resampled(n_items: int, seed: int, n: int = BOOTSTRAP) -> torch.Tensor:
    """``n`` seeded resamples (rows) of ``n_items`` indices drawn with replacement. CPU
    indices (one generator on every device); they index a tensor on any device."""
    gen = torch.Generator().manual_seed(seed)
    return torch.randint(0, n_items, (n, n_items), generator=gen)


def interval95(draws: torch.Tensor) -> tuple[float, float]:
    """Percentile 95% interval of bootstrap ``draws``, on their device."""
    lo, hi = torch.quantile(draws, draws.new_tensor([0.025, 0.975])).tolist()
    return float(lo), float(hi)
