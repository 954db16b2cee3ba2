"""Is a pix2pix fit going wrong? Three classic failures, watched on smoothed losses.

1. The generator's L1 to the real target climbs back up: its moving average rises above
   ``factor`` times the best moving average seen (an unstable learning rate undoing what
   was learned).
2. The discriminator wins outright: its loss average stays below ``D_FLOOR`` while the
   generator's adversarial loss average stays above ``ADV_CEILING`` (no useful gradient is
   left for the generator).
3. The game blows up: the discriminator's loss average stays above ``D_CEILING``, far
   worse than chance (0.69), i.e. D is confidently wrong step after step.

Averages are exponential with span ``window`` generator steps; nothing is judged before
``window`` steps (early losses are noisy by nature) and conditions 2 and 3 must hold for
``window`` steps in a row: on the translators recipe's real cGAN fit, D wins for a while
(D loss 0.02, adversarial 5.3 around step 80) and recovers, which is not divergence.
The first event is kept; the fit goes on (its metrics say what happened).
"""

from __future__ import annotations

from typing import Any

D_FLOOR = 0.01  # halved BCE of real + fake: 0.69 at chance
ADV_CEILING = 7.0  # -log(sigmoid(logit)) = 7: D gives fakes < 0.1 % chance of being real
D_CEILING = 3.0  # D is confidently wrong (chance is 0.69)


class DivergenceMonitor:
    """Feeds on (d_loss, g_adv, g_l1) each generator step; ``event`` is the first divergence."""

    def __init__(self, window: int = 50, factor: float = 3.0) -> None:
        self.window = window
        self.factor = factor
        self.alpha = 2.0 / (window + 1)
        self.steps = 0
        self.ema: dict[str, float] = {}
        self.best_l1 = float("inf")
        self.streak = {"d_wins": 0, "d_lost": 0}
        self.event: dict[str, Any] | None = None

    def update(self, d_loss: float, g_adv: float, g_l1: float) -> dict[str, Any] | None:
        """Returns the event when this step is the first to show divergence, else None."""
        self.steps += 1
        for key, value in (("d_loss", d_loss), ("g_adv", g_adv), ("g_l1", g_l1)):
            prev = self.ema.get(key, value)
            self.ema[key] = prev + self.alpha * (value - prev)
        if self.steps < self.window:
            return None
        l1, d, adv = self.ema["g_l1"], self.ema["d_loss"], self.ema["g_adv"]
        self.best_l1 = min(self.best_l1, l1)
        wins = d < D_FLOOR and adv > ADV_CEILING
        self.streak["d_wins"] = self.streak["d_wins"] + 1 if wins else 0
        self.streak["d_lost"] = self.streak["d_lost"] + 1 if d > D_CEILING else 0
        why = None
        if l1 > self.factor * self.best_l1:
            why = (
                f"generator L1 average {l1:.4f} is {l1 / self.best_l1:.1f}x its best "
                f"{self.best_l1:.4f}"
            )
        elif self.streak["d_wins"] >= self.window:
            why = (
                f"discriminator wins: D loss average {d:.4f}, G adversarial average "
                f"{adv:.2f} for {self.window} steps"
            )
        elif self.streak["d_lost"] >= self.window:
            why = f"unstable game: D loss average {d:.2f} (chance 0.69) for {self.window} steps"
        if why is None or self.event is not None:
            return None
        self.event = {"step": self.steps, "why": why}
        return self.event

    def state_dict(self) -> dict[str, Any]:
        """Plain values, stored in Lightning checkpoints so a resumed fit judges the same."""
        return {
            "steps": self.steps,
            "ema": dict(self.ema),
            "best_l1": self.best_l1,
            "streak": dict(self.streak),
            "event": self.event,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.steps = int(state["steps"])
        self.ema = {k: float(v) for k, v in state["ema"].items()}
        self.best_l1 = float(state["best_l1"])
        self.streak = {k: int(v) for k, v in state["streak"].items()}
        self.event = state["event"]
