"""Translators: simulated depth -> realistic tactile images, behind one registry."""

from tactile_bench.translators.base import (
    Translator,
    TranslatorConfig,
    foreground_to_image,
    image_to_foreground,
)
from tactile_bench.translators.registry import create_translator, discover, translator_class

__all__ = [
    "Translator",
    "TranslatorConfig",
    "create_translator",
    "discover",
    "foreground_to_image",
    "image_to_foreground",
    "translator_class",
]
