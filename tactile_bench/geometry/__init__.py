"""Geometry: braille blocks (dot patterns, meshes) and contact-pose protocols."""

from tactile_bench.geometry.braille import (
    BRAILLE_DOTS,
    CHARACTERS,
    BrailleSpec,
    braille_mesh,
    dot_positions,
)
from tactile_bench.geometry.contacts import (
    PRESS_DEPTHS_MM,
    Poses,
    classifier_protocol,
    finetune_test_protocol,
)

__all__ = [
    "BRAILLE_DOTS",
    "CHARACTERS",
    "PRESS_DEPTHS_MM",
    "BrailleSpec",
    "Poses",
    "braille_mesh",
    "classifier_protocol",
    "dot_positions",
    "finetune_test_protocol",
]
