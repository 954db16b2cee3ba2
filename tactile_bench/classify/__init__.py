"""Braille classifier: a ResNet-18-topology net, its LightningModule, training and metrics."""

from tactile_bench.classify.model import NUM_CLASSES, ResNetClassifier, count_flops
from tactile_bench.classify.module import BrailleClassifier
from tactile_bench.classify.train import (
    ClassifierConfig,
    evaluate,
    predict,
    recalibrate_batchnorm,
    train_classifier,
)

__all__ = [
    "NUM_CLASSES",
    "BrailleClassifier",
    "ClassifierConfig",
    "ResNetClassifier",
    "count_flops",
    "evaluate",
    "predict",
    "recalibrate_batchnorm",
    "train_classifier",
]
