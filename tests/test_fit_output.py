"""A fit prints progress and results, not third-party notices: Lightning's litlogger tip,
torch's LeafSpec deprecation (raised inside Lightning) and "`weights_only` was not set" at
every checkpoint are gone, and only those (issue 20)."""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import pytest
from lightning.pytorch.demos.boring_classes import BoringModel

from tactile_bench.testing import tiny_pairs
from tactile_bench.training import (
    EVERY_KEY,
    LITLOGGER_TIP,
    ROUTINE_NOTICES,
    lightning_notices_off,
)
from tactile_bench.translators import create_translator


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@pytest.fixture
def lightning_log() -> _Collect:
    """Every message Lightning logs (its loggers do not propagate to pytest's capture)."""
    logger = logging.getLogger("lightning.pytorch")
    handler, level = _Collect(), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    yield handler
    logger.removeHandler(handler)
    logger.setLevel(level)


def _leafspec_warning() -> None:
    """What Lightning does at every fit: build a torch ``LeafSpec`` in its own module."""
    from lightning.pytorch.utilities._pytree import _tree_flatten

    _tree_flatten(1.0)


def test_the_notices_exist_without_the_filter(lightning_log: _Collect) -> None:
    # the test below would pass vacuously if Lightning or torch dropped them
    import lightning as L

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _leafspec_warning()
        L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False)
    assert any("LeafSpec" in str(w.message) for w in caught)
    assert any(m.startswith(LITLOGGER_TIP) for m in lightning_log.messages)
    assert any(m.startswith("GPU available: ") for m in lightning_log.messages)


def test_only_those_notices_are_filtered(lightning_log: _Collect) -> None:
    import lightning as L

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with lightning_notices_off():
            _leafspec_warning()
            L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False)
            warnings.warn("another deprecation", FutureWarning, stacklevel=1)
            logging.getLogger("lightning.pytorch.utilities.rank_zero").info("another tip")
    assert [str(w.message) for w in caught] == ["another deprecation"]
    assert not any(m.startswith(ROUTINE_NOTICES) for m in lightning_log.messages)
    assert "another tip" in lightning_log.messages
    # and the filter is gone afterwards
    L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False)
    assert any(m.startswith(LITLOGGER_TIP) for m in lightning_log.messages)


def test_a_checkpointed_fit_logs_none_of_them(tmp_path: Path, lightning_log: _Collect) -> None:
    translator = create_translator(
        "cgan",
        {"generator_channels": 4, "discriminator_channels": 4, "batch_size": 6, "max_steps": 4},
    )
    depth, foreground = tiny_pairs(n=12, size=32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        translator.fit_pairs(
            depth, foreground, tmp_path, {"enable_progress_bar": False, EVERY_KEY: 1}
        )
    assert (tmp_path / "checkpoints/last.ckpt").is_file()
    assert not [w for w in caught if "LeafSpec" in str(w.message)]
    noise = [
        m for m in lightning_log.messages if m.startswith(ROUTINE_NOTICES) or "weights_only" in m
    ]
    assert noise == []  # that they are logged without the filter: the test below


def test_the_stop_line_is_logged_without_the_filter(
    tmp_path: Path, lightning_log: _Collect
) -> None:
    import lightning as L

    trainer = L.Trainer(
        max_steps=1,
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        default_root_dir=str(tmp_path),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # LeafSpec: the tests above
        trainer.fit(BoringModel())
    assert any(m.startswith("`Trainer.fit` stopped: ") for m in lightning_log.messages)
