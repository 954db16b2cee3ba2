"""The translator contract for every built-in translator, and a smoke check of every registered one.

Each built-in gets a TranslatorContract class with a config small enough to fit in seconds;
a built-in (registered by this distribution) without one fails ``test_every_builtin_...``.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch

from tactile_bench.sensor.surrogate import PROFILE_DIR
from tactile_bench.testing import TranslatorContract, tiny_pairs
from tactile_bench.translators import create_translator, registry

# two small configs, kept compact
# fmt: off
TINY_DIFFUSION = {
    "preset": "tiny", "image_size": 32, "max_steps": 2, "batch_size": 4,
    "sampler": "dpmsolver++", "steps": 3,
}
TINY_CGAN = {
    "max_steps": 2, "batch_size": 4, "generator_channels": 4, "num_downs": 3,
    "discriminator_channels": 4, "discriminator_layers": 2,
}
# fmt: on


class TestDiffusionContract(TranslatorContract):
    name = "diffusion"
    tiny_config = TINY_DIFFUSION


class TestCGANContract(TranslatorContract):
    name = "cgan"
    tiny_config = TINY_CGAN

    def test_translate_ignores_the_generator(self, tmp_path: Path) -> None:
        translator = self.fitted(tmp_path)
        depth, _ = tiny_pairs(n=2, size=self.size)
        background = torch.full((3, self.size, self.size), 100.0)
        a = translator.translate(depth, background, torch.Generator().manual_seed(0))
        b = translator.translate(depth, background, torch.Generator().manual_seed(1))
        torch.testing.assert_close(a, b)

    def test_max_steps_counts_generator_updates(self, tmp_path: Path) -> None:
        class CountBatches(L.Callback):
            batches = 0

            def on_train_batch_end(self, *args: object) -> None:
                CountBatches.batches += 1

        translator = self.make()
        depth, foreground = tiny_pairs(n=16, size=self.size)
        trainer = {"enable_progress_bar": False, "callbacks": [CountBatches()]}
        translator.fit_pairs(depth, foreground, tmp_path, trainer)
        assert CountBatches.batches == TINY_CGAN["max_steps"]

    def test_fit_moves_towards_targets(self, tmp_path: Path) -> None:
        depth, foreground = tiny_pairs(n=16, size=self.size)
        translator = create_translator(self.name, {**TINY_CGAN, "max_steps": 40, "lr": 2e-3})
        translator.eval()
        with torch.no_grad():
            before = (translator.translate_foreground(depth) - foreground).abs().mean()
        translator.fit_pairs(depth, foreground, tmp_path, {"enable_progress_bar": False})
        translator.eval()
        with torch.no_grad():
            after = (translator.translate_foreground(depth) - foreground).abs().mean()
        assert after < 0.5 * before


class TestLightingAugContract(TranslatorContract):
    name = "lighting_aug"

    def test_seed_changes_lighting_and_spares_global_rng(self) -> None:
        translator = self.make()
        depth, _ = tiny_pairs(n=4, size=self.size)
        background = torch.full((3, self.size, self.size), 120.0)
        torch.manual_seed(123)
        expected_next = torch.rand(3)
        torch.manual_seed(123)
        a = translator.translate(depth, background, torch.Generator().manual_seed(0))
        b = translator.translate(depth, background, torch.Generator().manual_seed(1))
        torch.testing.assert_close(torch.rand(3), expected_next)  # global RNG untouched
        assert (a - b).abs().mean() > 1.0

    def test_differs_from_plain_sim(self) -> None:
        depth, _ = tiny_pairs(n=4, size=self.size)
        background = torch.full((3, self.size, self.size), 120.0)
        augmented = self.make().translate(depth, background, torch.Generator().manual_seed(0))
        gen = torch.Generator().manual_seed(0)
        sim = create_translator("sim").translate(depth, background, gen)
        assert (augmented - sim).abs().mean() > 1.0


CONTRACTS = {c.name: c for c in (TestDiffusionContract, TestCGANContract, TestLightingAugContract)}
COVERED_IN_TEST_TRANSLATORS = {"sim"}
COVERED_IN_TEST_CALIBRATED = {"calibrated"}  # tests/test_calibrated.py
COVERED_IN_TEST_PAIRED_DATA = {"profile"}  # tests/test_paired_data_stage.py (TestProfileContract)
#: translators that need a config key to exist at all: their tiny configs
REQUIRED_CONFIG = {"profile": {"profile": str(PROFILE_DIR / "digit.yaml")}}


def test_every_builtin_translator_has_a_contract() -> None:
    builtins = {n for n, e in registry.discover().items() if e.distribution == "tactile_bench"}
    covered = COVERED_IN_TEST_TRANSLATORS | COVERED_IN_TEST_CALIBRATED | COVERED_IN_TEST_PAIRED_DATA
    assert builtins - set(CONTRACTS) - covered == set()


@pytest.mark.parametrize("name", sorted(registry.discover()))
def test_every_registered_translator_translates_unfitted(name: str) -> None:
    """Any registered translator, built-in or plugin: default config, no fit, valid images."""
    config = CONTRACTS[name].tiny_config if name in CONTRACTS else REQUIRED_CONFIG.get(name)
    translator = create_translator(name, config)
    depth, _ = tiny_pairs(n=2, size=32, seed=7)
    image = translator.translate(depth, torch.full((3, 32, 32), 110.0), torch.Generator())
    assert image.shape == (2, 3, 32, 32)
    assert torch.isfinite(image).all() and image.min() >= 0 and image.max() <= 255
