"""Stage ``compare_translators``: image similarity of several translators on the same test set,
and a sample grid (depth | real | each translator) for a few characters."""

from __future__ import annotations

from typing import Any

import torch
from pydantic import Field

from tactile_bench.data.braille import BrailleSet
from tactile_bench.hardware import compute_device
from tactile_bench.io import atomic_write_json, atomic_write_text, load_npz
from tactile_bench.metrics.encoder import fit_encoder, kid
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind
from tactile_bench.pipeline.stages.paired_data import class_names
from tactile_bench.report.figures import sample_grid_png

PAPER_SIMILARITY = {"diffusion": (0.908, 36.02), "cgan": (0.879, 47.99)}


class CompareConfig(StageConfig):
    """How many characters the sample grid shows; how long the KID encoder trains."""

    samples: int = Field(default=8, ge=1, le=27, description="characters in the sample grid")
    encoder_steps: int = Field(
        default=300, ge=1, description="training steps of the KID feature encoder"
    )


def _picks(labels: torch.Tensor, k: int) -> list[int]:
    """Up to ``k`` contacts for the grid: the first of each label, then (fewer labels than
    rows: a user's folder with one label or none) the next contacts in order."""
    first = [int(torch.nonzero(labels == c).flatten()[0]) for c in torch.unique(labels)]
    taken = set(first)
    rest = [i for i in range(len(labels)) if i not in taken]
    return (first + rest)[:k]


def _subset_size(n: int) -> int:
    """KID's subset size: 100 (torchmetrics' default), at most half the test set, so that
    on a small set (a sensor's held-out presses) the subsets differ and the std means
    something (every subset of a 24-pair set at 100 was the whole set: std 0)."""
    return max(2, min(100, n // 2))


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: CompareConfig = ctx.config
    data = ctx.input("data")
    test = BrailleSet.load(data.path("test"))
    # the distribution distance uses an encoder of our own, trained on real images that are
    # not in the test set (no downloaded Inception weights)
    encoder = fit_encoder(
        BrailleSet.load(data.path("finetune")).real.float(),
        steps=config.encoder_steps,
        seed=ctx.seed,
        device=compute_device(ctx.trainer.get("accelerator")),
    )
    real_features = encoder.features(test.real.float())
    rows = []
    picks = _picks(test.labels, config.samples)
    columns = {"depth": test.depth[picks], "real": test.real[picks]}
    names = class_names(data, int(test.labels.max()) + 1)
    for result in ctx.inputs["translated"]:
        name = result.metrics["translator"]
        sim = result.metrics["test_similarity"]
        paper = PAPER_SIMILARITY.get(name)
        rows.append(
            {
                "translator": name,
                "stage": result.name,
                **sim,
                "paper_ssim": paper[0] if paper else None,
                "paper_mse": paper[1] if paper else None,
            }
        )
        images = torch.from_numpy(load_npz(result.path("test"), ("images",))["images"])
        rows[-1]["kid"], rows[-1]["kid_std"] = kid(
            encoder.features(images.float()), real_features, subset_size=_subset_size(len(test))
        )
        title = name if name not in columns else f"{name}\n{result.name}"
        columns[title] = images[picks]
    sample_grid_png(
        columns,
        [names[int(test.labels[i])] for i in picks],
        ctx.directory / "samples.png",
        title="test contacts",
    )
    lines = [
        "| translator | stage | SSIM | MSE | KID, own encoder (± std) | paper SSIM | paper MSE |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        paper = "- | -"
        if r["paper_ssim"] is not None:
            paper = f"{r['paper_ssim']:.3f} | {r['paper_mse']:.2f}"
        lines.append(
            f"| {r['translator']} | {r['stage']} | {r['ssim']:.3f} | {r['mse']:.2f} | "
            f"{r['kid']:.4f} ± {r['kid_std']:.4f} | {paper} |"
        )
    lines.append(
        f"\nSSIM and MSE on 0-255 against the real image of each of the {len(test)} test "
        "contacts, as the paper reports them. KID compares the distributions of translated and "
        "real test images in the features of an autoencoder trained from scratch on the real "
        "fine-tuning images (lower is closer; no downloaded Inception weights)."
    )
    atomic_write_text(ctx.directory / "similarity.md", "\n".join(lines) + "\n")
    atomic_write_json(ctx.directory / "similarity.json", {"rows": rows, "n": len(test)})
    outputs = {
        "similarity_md": "similarity.md",
        "similarity_json": "similarity.json",
        "samples": "samples.png",
    }
    return outputs, {"rows": rows}


STAGE = StageKind(
    name="compare_translators",
    description="SSIM/MSE of several translators on the braille test set, and a sample grid",
    config_model=CompareConfig,
    run=_run,
    input_slots={"data": True, "translated": True},
    publish=("similarity_md", "samples"),
)
