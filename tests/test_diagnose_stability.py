"""The depth-split check: which pairs it fits and holds out, and when it disagrees."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
import torch

from tactile_bench.diagnose.ranking import EffectFit
from tactile_bench.diagnose.stability import MIN_PAIRS, check, depth_halves, warning
from tactile_bench.diagnose.which import WhichResult


@dataclass
class _Entry:
    effect: str
    confusable_with: list[str] = field(default_factory=list)


def _depth(peaks: list[float]) -> torch.Tensor:
    depth = torch.zeros(len(peaks), 1, 4, 4)
    depth[:, 0, 1, 2] = torch.tensor(peaks)
    return depth


def test_halves_are_the_shallowest_and_deepest_presses_capped() -> None:
    peaks = [0.9, 0.1, 0.5, 0.3, 0.7, 0.2, 0.8, 0.4, 0.6, 1.0]
    shallow, deep = depth_halves(_depth(peaks))
    assert sorted(peaks[i] for i in shallow) == [0.1, 0.2, 0.3, 0.4, 0.5]
    assert sorted(peaks[i] for i in deep) == [0.6, 0.7, 0.8, 0.9, 1.0]
    shallow, deep = depth_halves(_depth(peaks), n_max=4)
    assert sorted(peaks[i] for i in shallow) == [0.1, 0.2]
    assert sorted(peaks[i] for i in deep) == [0.9, 1.0]


def test_ties_split_the_same_way_every_time() -> None:
    depth = _depth([0.5] * 12)
    first, second = depth_halves(depth), depth_halves(depth)
    assert all(torch.equal(a, b) for a, b in zip(first, second, strict=True))
    assert set(first[0].tolist()).isdisjoint(first[1].tolist())


def test_rerun_fits_the_shallow_half_and_scores_the_deep_half() -> None:
    peaks = [0.2, 1.2, 0.4, 1.0, 0.3, 1.1, 0.1, 0.9, 1.3, 0.5]
    seen = {}

    def rerun(fit_idx: torch.Tensor, held_idx: torch.Tensor) -> list[_Entry]:
        seen["fit"], seen["held"] = fit_idx, held_idx
        return [_Entry("blur")]

    result = check([_Entry("blur")], _depth(peaks), rerun)
    assert result is not None and result.agrees and result.named_first == "blur"
    assert max(peaks[i] for i in seen["fit"]) < min(peaks[i] for i in seen["held"])
    assert result.depth_fit_mm == pytest.approx(0.5) and result.depth_held_mm == pytest.approx(0.9)
    assert (result.n_fit, result.n_held) == (5, 5)


@pytest.mark.parametrize(
    ("named", "agrees"),
    [
        (["spread"], True),  # a selected effect, not the first
        (["gains"], True),  # a rival the held-out pairs could not tell from the first
        ([], True),  # nothing selected on the depth split contradicts nothing
        (["tone_curve", "blur"], False),  # another effect named first
    ],
)
def test_agrees_only_with_the_selection_or_its_rivals(named: list[str], agrees: bool) -> None:
    ranking = [_Entry("blur", ["gains"]), _Entry("spread")]
    result = check(ranking, _depth([0.1 * i for i in range(10)]), lambda f, h: map(_Entry, named))
    assert result is not None and result.agrees is agrees
    assert result.accepted == ["blur", "gains", "spread"]
    assert (warning(result) is None) is agrees


def test_nothing_to_check_without_a_selection_or_with_too_few_pairs() -> None:
    def rerun(fit_idx: torch.Tensor, held_idx: torch.Tensor) -> list[_Entry]:
        raise AssertionError("must not re-run")

    assert check([], _depth([0.1 * i for i in range(20)]), rerun) is None
    assert check([_Entry("blur")], _depth([0.1] * (MIN_PAIRS - 1)), rerun) is None


def test_the_warning_names_the_effect_and_the_depths() -> None:
    result = check(
        [_Entry("blur")], _depth([0.1 * i for i in range(10)]), lambda f, h: [_Entry("x")]
    )
    text = warning(result)
    assert text is not None and "names x first" in text and "blur" in text
    assert "0.40 mm" in text and "0.50 mm" in text
    assert warning(None) is None


def test_an_unstable_explanation_is_flagged_even_with_a_small_residual() -> None:
    row = EffectFit("blur", {}, 1.0, 0.01, 0.99, 0.98, 1.0)
    result = WhichResult([row], [row], unexplained=0.01, residual_flagged=False, gap_metric="g")
    assert not result.flagged and not result.unstable  # not checked: nothing to flag
    result.stability = check([row], _depth([0.1 * i for i in range(10)]), lambda f, h: [row])
    assert not result.flagged
    other = EffectFit("tone", {}, 1.0, 0.01, 0.99, 0.98, 1.0)
    result.stability = check([row], _depth([0.1 * i for i in range(10)]), lambda f, h: [other])
    assert result.unstable and result.flagged
    d = result.to_dict()
    assert d["flagged"] and d["unstable"] and d["stability"]["named_first"] == "tone"
