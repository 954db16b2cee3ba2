"""How fast a recipe's classifier leaves its loss plateau: one setting changed at a time.

    python scripts/classifier_lr_ab.py RUN_DIR ROW LR EPOCHS SEED [--width 8] [--batch 32]

RUN_DIR is a finished ``fit`` run (its ``braille-*`` stage is read); ROW is ``real`` or
``sim`` (the images trained on). The classifier trains on one thread, on 90% of the
classifier set (the rest is the in-domain held-out set), and is tested on the real test
contacts. Prints one JSON line: test and held-out accuracy and the training's seconds.
A held-out accuracy far below 1 means the net had not converged; the test accuracy of the
``sim`` row is the reality gap, which moves by 10-15 points between seeds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from tactile_bench.classify.train import ClassifierConfig, evaluate, train_classifier
from tactile_bench.translators import image_to_foreground


def _foreground(arrays: np.lib.npyio.NpzFile, images: str) -> torch.Tensor:
    return image_to_foreground(
        torch.from_numpy(arrays[images]).float(),
        torch.from_numpy(arrays[f"{images}_background"]).float(),
    )


def main() -> None:
    """Train one classifier with the given settings and print its accuracies."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("row", choices=("real", "sim"))
    parser.add_argument("lr", type=float)
    parser.add_argument("epochs", type=int)
    parser.add_argument("seed", type=int)
    parser.add_argument("--width", type=int, default=8)
    parser.add_argument("--batch", type=int, default=32)
    args = parser.parse_args()
    torch.set_num_threads(1)
    braille = next(args.run_dir.glob("braille-*"))
    train, test = np.load(braille / "classifier.npz"), np.load(braille / "classifier_test.npz")
    x, y = _foreground(train, args.row), torch.from_numpy(train["pose_labels"])
    order = torch.randperm(len(y), generator=torch.Generator().manual_seed(args.seed))
    held, fit = order[: len(y) // 10], order[len(y) // 10 :]
    config = ClassifierConfig(
        width=args.width,
        blocks=(1, 1, 1, 1),
        batch_size=args.batch,
        lr=args.lr,
        epochs=args.epochs,
        seed=args.seed,
    )
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        model = train_classifier(
            x[fit],
            y[fit],
            config,
            out,
            loggers=[],
            trainer_kwargs={"enable_progress_bar": False, "enable_checkpointing": False},
        )
    seconds = time.perf_counter() - start
    test_fg, test_labels = _foreground(test, "real"), torch.from_numpy(test["pose_labels"])
    result = {
        **vars(args) | {"run_dir": str(args.run_dir)},
        "test": round(evaluate(model, test_fg, test_labels)["accuracy"], 4),
        "heldout": round(evaluate(model, x[held], y[held])["accuracy"], 4),
        "seconds": round(seconds, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
