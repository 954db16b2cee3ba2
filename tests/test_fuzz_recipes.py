"""Random recipe documents either load or raise TactileBenchError, never anything else."""

from __future__ import annotations

import tempfile
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_bench.errors import TactileBenchError
from tactile_bench.pipeline.recipe import load_recipe

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-5, 2000),
    st.floats(allow_nan=True),
    st.text(max_size=8),
    st.sampled_from(["sim", "braille", "classify", "translate", "digit"]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)
stage = st.fixed_dictionaries(
    {
        "name": st.sampled_from(["a", "b", "braille", "x y"]),
        "kind": st.sampled_from(["braille_data", "translate", "classify", "report", "nope"]),
    },
    optional={
        "inputs": st.dictionaries(
            st.sampled_from(["data", "images", "rows", "zz"]),
            st.sampled_from(["a", "b", "braille"]),
            max_size=2,
        ),
        "config": st.dictionaries(
            st.sampled_from(["chars", "n_test", "translator", "row", "seeds", "bogus"]),
            values,
            max_size=3,
        ),
    },
)
documents = st.one_of(
    values,
    st.fixed_dictionaries(
        {"name": st.text(max_size=6), "stages": st.lists(stage, max_size=3)},
        optional={"seed": values, "trainer": values, "extra": values},
    ),
)


def _loads_or_fails_in_one_line(path: Path) -> None:
    """Any other exception type propagates and fails the test."""
    try:
        recipe = load_recipe(path)
    except TactileBenchError as exc:
        message = str(exc)
        assert message and "\n" not in message.strip()
    else:
        assert recipe.stages


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_random_recipe_documents(doc: object) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.yaml"
        path.write_text(yaml.safe_dump(doc))
        _loads_or_fails_in_one_line(path)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.yaml"
        path.write_bytes(data)
        _loads_or_fails_in_one_line(path)
