"""A contract every translator must pass, as a pytest mixin plugin authors can reuse.

```python
from tactile_bench.testing import TranslatorContract

class TestMyTranslator(TranslatorContract):
    name = "my_translator"          # as registered in the entry-point group
    tiny_config = {"max_steps": 2}  # small enough to fit in seconds on a CPU
```
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch

from tactile_bench.data.synthetic import tiny_pairs
from tactile_bench.translators import Translator, create_translator, translator_class


def available_devices() -> list[str]:
    """The devices a test runs on here: the CPU always, CUDA when there is a GPU."""
    return ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]


TINY_DIFFUSION = {"preset": "tiny", "image_size": 32, "max_steps": 2, "batch_size": 4}
TINY_CLASSIFIER = {"width": 4, "epochs": 1, "batch_size": 8}


def shrink_recipe(doc: dict[str, Any]) -> dict[str, Any]:
    """A recipe document (parsed YAML) with every size made tiny and its stages, inputs and
    rows kept: the chain a user runs, in seconds on a CPU (tests of shipped recipes)."""
    for stage in doc["stages"]:
        config = stage.setdefault("config", {})
        kind = stage["kind"]
        if kind == "braille_data":
            config.update(
                chars="ABC",
                n_finetune=45,  # 20% of it: 9, enough for lighting_aug's noise estimate (8)
                n_test=12,
                n_classifier=48,
                n_classifier_test=12,
                image_size=32,
                second_unit="digit-b",
            )
        elif kind == "ycb_slide_data":
            config.update(n_pairs=24, objects=["005_tomato_soup_can"], image_size=32)
        elif kind == "fit_translator":
            small = TINY_DIFFUSION if config["translator"] == "diffusion" else {"max_steps": 2}
            if config["translator"] == "calibrated":  # one candidate keeps its diagnosis short
                small = {"candidates": ["defocus_blur"]}
            config["translator_config"] = {
                **config.get("translator_config", {}),  # e.g. lighting_aug's mode: image
                **small,
                "batch_size": 4,
            }
        elif kind == "translate" and stage["name"].startswith("translate_diffusion"):
            config["translator_config"] = {**config.get("translator_config", {}), "steps": 2}
        elif kind == "compare_translators":
            config["encoder_steps"] = 2
        elif kind == "classify":
            config.update(seeds=[0, 1], classifier=TINY_CLASSIFIER, finetune_epochs=1)
    return doc


class TranslatorContract:
    """Construct, fit a few steps, translate, save/load, determinism: for one registered name."""

    name: ClassVar[str] = ""
    tiny_config: ClassVar[dict[str, Any]] = {}
    size: ClassVar[int] = 32

    def make(self) -> Translator:
        return create_translator(self.name, dict(self.tiny_config))

    def fitted(self, tmp_path: Path) -> Translator:
        translator = self.make()
        depth, foreground = tiny_pairs(size=self.size)
        translator.fit_pairs(depth, foreground, tmp_path, {"enable_progress_bar": False})
        return translator

    def test_registered_under_its_name(self) -> None:
        assert translator_class(self.name).name == self.name

    def test_translate_shape_and_range(self, tmp_path: Path) -> None:
        translator = self.fitted(tmp_path)
        depth, _ = tiny_pairs(n=3, size=self.size, seed=1)
        background = torch.full((3, self.size, self.size), 120.0)
        image = translator.translate(depth, background, torch.Generator().manual_seed(0))
        assert image.shape == (3, 3, self.size, self.size)
        assert image.dtype == torch.float32
        assert torch.isfinite(image).all()
        assert image.min() >= 0.0 and image.max() <= 255.0

    def test_save_load_round_trip(self, tmp_path: Path) -> None:
        translator = self.fitted(tmp_path)
        path = translator.save(tmp_path / "translator.pt")
        loaded = type(translator).load(path)
        depth, _ = tiny_pairs(n=2, size=self.size, seed=2)
        background = torch.full((3, self.size, self.size), 100.0)
        before = translator.translate(depth, background, torch.Generator().manual_seed(3))
        after = loaded.translate(depth, background, torch.Generator().manual_seed(3))
        torch.testing.assert_close(before, after)

    @pytest.fixture(params=available_devices())
    def device(self, request: pytest.FixtureRequest) -> torch.device:
        return torch.device(request.param)

    def test_translates_on_every_device(self, tmp_path: Path, device: torch.device) -> None:
        """Moved to ``device`` (the CPU, and CUDA where there is one), it translates inputs
        there, returns images there, and draws the same noise from a CPU generator."""
        translator = self.fitted(tmp_path)
        depth, _ = tiny_pairs(n=2, size=self.size, seed=6)
        background = torch.full((3, self.size, self.size), 110.0)
        on_cpu = translator.translate(depth, background, torch.Generator().manual_seed(7))
        translator.to(device)
        image = translator.translate(
            depth.to(device), background.to(device), torch.Generator().manual_seed(7)
        )
        assert image.device.type == device.type and image.shape == on_cpu.shape
        # the same draws and weights; kernels and precision differ between devices
        assert (image.cpu() - on_cpu).abs().mean() < 2.0

    def test_deterministic_under_seed(self, tmp_path: Path) -> None:
        depth, _ = tiny_pairs(n=2, size=self.size, seed=4)
        background = torch.full((3, self.size, self.size), 90.0)
        outputs = []
        for run in range(2):
            translator = self.fitted(tmp_path / f"run{run}")
            outputs.append(
                translator.translate(depth, background, torch.Generator().manual_seed(5))
            )
        torch.testing.assert_close(outputs[0], outputs[1])
