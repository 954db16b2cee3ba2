"""tactile_bench: closing the sim-to-real gap of vision-based tactile sensors (DIGIT-class)."""

__version__ = "0.1.0"
