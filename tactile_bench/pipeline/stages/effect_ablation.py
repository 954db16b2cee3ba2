"""Stage ``effect_ablation``: which surrogate effects carry the reality gap of a classifier.

The classifier (trained on sim, say) is re-tested on the same test contacts rendered by the
surrogate with one effect switched off at a time. The accuracy an effect's removal gives
back is that effect's share of the gap; "all off" is the surrogate reduced to the noise-free
simulator. This is a controlled experiment on the surrogate (whose effects we know), not the
blind gap diagnosis, which reads only data.
"""

from __future__ import annotations

from typing import Any

import torch
from matplotlib.figure import Figure
from pydantic import Field

from tactile_bench.classify.store import load_classifier
from tactile_bench.classify.train import evaluate
from tactile_bench.data.braille import BrailleSet
from tactile_bench.errors import TactileBenchError
from tactile_bench.geometry.braille import CHARACTERS, BrailleSpec
from tactile_bench.io import atomic_write_json, atomic_write_text
from tactile_bench.pipeline.stages.base import StageConfig, StageContext, StageKind, real_sensor
from tactile_bench.report.figures import save_figure
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.translators import image_to_foreground


class AblationConfig(StageConfig):
    """Which classifier seed to probe (the effects are those of the data's real sensor)."""

    seed: int = Field(default=0, description="the classify stage's seed whose model is probed")


def _accuracy(
    model: Any, sensor: SurrogateDigit, test: BrailleSet, bank: Any, gel: GelSpec, seed: int
) -> float:
    image = sensor.render(bank, test.poses, gel, torch.Generator().manual_seed(seed))
    fg = image_to_foreground(image, sensor.background(gel))
    n_classes = int(model.hparams.num_classes)
    return float(evaluate(model, fg, test.labels, num_classes=n_classes)["accuracy"])


def _bar_png(rows: list[dict[str, Any]], base: float, path: Any) -> None:
    fig = Figure(figsize=(7, 0.35 * len(rows) + 1.2))
    ax = fig.subplots()
    names = [r["effect"] for r in rows]
    gains = [100 * (r["accuracy"] - base) for r in rows]
    ax.barh(names[::-1], gains[::-1], color="tab:blue")
    ax.axvline(0, color="black", lw=0.8)
    ax.set_xlabel("accuracy gained on real test when the effect is switched off (points)")
    ax.set_title(f"which effects carry the gap (all effects on: {100 * base:.1f}%)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def _run(ctx: StageContext) -> tuple[dict[str, str], dict[str, Any]]:
    config: AblationConfig = ctx.config
    data, clf = ctx.input("data"), ctx.input("classifier")
    if "real_sensor" not in data.metrics:
        raise TactileBenchError(
            f"stage {ctx.name}: data stage {data.name!r} ({data.kind}) has no surrogate "
            "real_sensor to switch effects off in; connect a braille_data stage"
        )
    model = load_classifier(clf.path(f"model_seed{config.seed}"))
    test = BrailleSet.load(data.path("classifier_test"))
    # a YAML path is read relative to the recipe's folder, as the data stage read it
    sensor = real_sensor(data.metrics["real_sensor"], ctx.recipe_dir)
    chars = tuple(CHARACTERS[: int(test.labels.max()) + 1])
    bank, gel = build_bank(chars, BrailleSpec()), GelSpec(size=test.depth.shape[-1])
    base = _accuracy(model, sensor, test, bank, gel, ctx.seed)
    rows = []
    for name in sensor.effects_enabled:
        acc = _accuracy(model, sensor.without(name), test, bank, gel, ctx.seed)
        rows.append({"effect": name, "accuracy": acc, "gain": acc - base})
    rows.sort(key=lambda r: r["gain"], reverse=True)
    all_off = _accuracy(model, sensor.only(), test, bank, gel, ctx.seed)
    sim = float(
        evaluate(
            model, test.foreground("sim"), test.labels, num_classes=int(model.hparams.num_classes)
        )["accuracy"]
    )
    result = {
        "classifier": clf.name,
        "all_effects_on": base,
        "all_effects_off": all_off,
        "sim_same_contacts": sim,
        "switch_off_one": rows,
    }
    atomic_write_json(ctx.directory / "ablation.json", result)
    _bar_png(rows, base, ctx.directory / "ablation.png")
    lines = ["| effect switched off | accuracy % | gain (points) |", "| --- | --- | --- |"]
    lines += [
        f"| {r['effect']} | {100 * r['accuracy']:.1f} | {100 * r['gain']:+.1f} |" for r in rows
    ]
    lines += [
        f"| (none: all effects on) | {100 * base:.1f} | |",
        f"| (all effects off) | {100 * all_off:.1f} | {100 * (all_off - base):+.1f} |",
        f"| (simulator with its noise) | {100 * sim:.1f} | {100 * (sim - base):+.1f} |",
    ]
    atomic_write_text(ctx.directory / "ablation.md", "\n".join(lines) + "\n")
    return {"ablation": "ablation.json", "figure": "ablation.png", "table": "ablation.md"}, {
        "all_effects_on": base,
        "all_effects_off": all_off,
        "top": rows[0]["effect"],
    }


STAGE = StageKind(
    name="effect_ablation",
    description="switch each surrogate effect off in turn: which ones carry a classifier's gap",
    config_model=AblationConfig,
    run=_run,
    input_slots={"data": True, "classifier": True},
    publish=("table", "figure"),
)
