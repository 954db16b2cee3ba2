"""``python -m tactile_bench bench``: measure this machine, write bench.json and bench.md.

One run measures, side by side: contact simulation, diffusion sampling (every sampler and
step count against the paper's 500-step DDPM, on the same network and contacts), training
throughput (fp32 / bf16 / channels_last), cost at 1x / 2x / 4x the work, peak memory, and
our differentiable JPEG against kornia's with libjpeg the reference. Asked for by name
(``--only``): the sections on another device, and the gap diagnosis at its defaults.
The machine is shared and noisy, so headline figures are ratios of measurements taken in
the same run; medians of several repetitions after a warm-up (see ``bench.timing``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import platform
import statistics
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from tactile_bench import allocator
from tactile_bench.bench import diagnosis, jpeg, sampling, simulation, startup, training
from tactile_bench.bench.device import DeviceBenchSizes, check_device, device_rows
from tactile_bench.bench.report import render_markdown
from tactile_bench.bench.threads import thread_settings
from tactile_bench.bench.timing import torch_threads
from tactile_bench.data.braille import BrailleSet, build_braille_sets
from tactile_bench.errors import TactileBenchError
from tactile_bench.hardware import machine_compute
from tactile_bench.io import atomic_write_json, atomic_write_text
from tactile_bench.sensor.background import sim_background
from tactile_bench.sensor.depth import GelSpec
from tactile_bench.sensor.heightfield import build_bank
from tactile_bench.sensor.optics import SimOptics
from tactile_bench.sensor.surrogate import SurrogateDigit
from tactile_bench.translators.diffusion import DiffusionConfig, DiffusionTranslator

SECTIONS = (
    "startup",
    "simulation",
    "sampling",
    "threads",
    "training",
    "seeds",
    "scaling",
    "jpeg",
)
#: sections run only when asked for (``--only``, or ``--device`` other than the CPU); the
#: diagnosis takes minutes at its default 300 pairs
OPTIONAL_SECTIONS = ("device", "diagnosis")
# inference settings the bench applies to a loaded checkpoint: the shipped defaults
INFERENCE_KEYS = ("sampler", "steps", "sample_batch_size", "precision", "channels_last")
# what the default sampler must reach (issue 8): vs DDPM-500 measured in the same run
TARGET_SPEEDUP, TARGET_SSIM_DROP, TARGET_IMAGES_PER_S = 25.0, 0.01, 10.0


@dataclass
class BenchConfig:
    """Sizes of every measurement; ``full()`` and ``quick()`` are the two CLI presets."""

    quick: bool = False
    seed: int = 0
    repeats: int = 3
    sim_contacts: int = 256
    sim_frames: int = 50
    n_finetune: int = 1080
    n_test: int = 837
    ddpm_images: int = 32
    default_images: int = 837
    variant_images: int = 64
    cases: tuple[tuple[str, int], ...] = (
        *((s, k) for s in ("ddim", "dpmsolver++", "unipc") for k in (1, 2, 4, 8)),
        ("dpmsolver++", 20),
    )
    presets: tuple[str, ...] = ("cpu-small", "cpu", "paper")
    preset_batch: int = 32
    conv_batch: int = 16
    train_warmup: int = 3
    train_steps: int = 10
    epoch_sizes: dict[str, tuple[int, ...]] = field(
        default_factory=lambda: {"translator": (128, 256, 512), "classifier": (540, 1080, 2160)}
    )
    seed_images: int = 2160
    fit_steps: int = 200
    fit_lr: float = 5e-4
    translator_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    jpeg_images: int = 32
    jpeg_native_images: int = 8
    jpeg_qualities: tuple[int, ...] = jpeg.QUALITIES
    diagnosis_pairs: int = 300
    diagnosis_size: int = 64
    diagnosis_candidates: tuple[str, ...] | None = None  # None: diagnose's default, all
    diagnosis_downstream: bool = True

    @classmethod
    def full(cls, **kw: Any) -> BenchConfig:
        return cls(**kw)

    @classmethod
    def quick_preset(cls, **kw: Any) -> BenchConfig:
        """Under 5 minutes on 2 idle cores: fewer contacts, images, steps and repetitions."""
        values: dict[str, Any] = dict(
            quick=True,
            repeats=2,
            sim_contacts=64,
            sim_frames=20,
            n_finetune=270,
            n_test=135,
            ddpm_images=8,
            default_images=64,
            variant_images=16,
            cases=tuple((s, k) for s in ("ddim", "dpmsolver++", "unipc") for k in (1, 2, 4)),
            presets=("cpu-small", "cpu"),
            preset_batch=8,
            conv_batch=2,
            train_warmup=1,
            train_steps=3,
            epoch_sizes={"translator": (32, 64, 128), "classifier": (120, 240, 480)},
            seed_images=480,
            fit_steps=40,
            jpeg_images=16,
            jpeg_native_images=4,
            diagnosis_pairs=60,
        )
        values.update(kw)
        return cls(**values)


def machine_info() -> dict[str, Any]:
    """Cores, threads, versions and load: what the figures depend on."""
    import diffusers
    import lightning

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "cpu": cpu,
        **machine_compute(),  # capability, native bf16, threads, what auto picks: as run.json
        "torch": torch.__version__,
        "diffusers": diffusers.__version__,
        "lightning": lightning.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "ld_preload": os.environ.get("LD_PRELOAD", ""),
        "malloc": allocator.describe(),
    }


def conv_probe(batch: int = 16, repeats: int = 3) -> dict[str, Any]:
    """One 3 x 3 convolution (64 -> 64 channels on batch x 64 x 64 x 64) in fp32 and under
    bf16 autocast, at the process's thread count: the cost of bf16 on this CPU in one number."""
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(batch, 64, 64, 64, generator=gen)
    conv = torch.nn.Conv2d(64, 64, 3, padding=1)
    out: dict[str, Any] = {
        "shape": f"{batch}x64x64x64, 64->64, 3x3",
        "threads": torch.get_num_threads(),
    }
    for name, bf16 in (("fp32", False), ("bf16", True)):
        times = []
        with torch.no_grad(), torch.autocast("cpu", torch.bfloat16, enabled=bf16):
            for _ in range(repeats + 1):  # the first call is oneDNN's kernel choice
                start = time.perf_counter()
                conv(x)
                times.append(time.perf_counter() - start)
        out[f"{name}_ms"] = 1000 * statistics.median(times[1:])
    out["bf16_over_fp32"] = out["bf16_ms"] / out["fp32_ms"]
    return out


def _loadavg() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def braille_data(path: str | None, cfg: BenchConfig, progress: bool) -> dict[str, BrailleSet]:
    """``finetune`` and ``test`` sets: from a braille_data stage folder, or simulated here."""
    if path:
        root = Path(path)
        test_path = root / "test.npz" if root.is_dir() else root
        sets = {"test": BrailleSet.load(test_path)}
        finetune = test_path.with_name("finetune.npz")
        if finetune.is_file():
            sets["finetune"] = BrailleSet.load(finetune)
            return sets
    else:
        sets = {}

    gel = GelSpec()
    built = build_braille_sets(
        build_bank(),
        gel,
        SimOptics(),
        sim_background(gel.size),
        SurrogateDigit.from_profile("digit"),
        seed=cfg.seed,
        n_finetune=cfg.n_finetune,
        n_test=cfg.n_test,
        n_classifier=27,
        n_classifier_test=27,
        progress=progress,
    )
    return {"finetune": built["finetune"], "test": built["test"], **sets}


def diffusion_translator(
    path: str | None, finetune: BrailleSet, cfg: BenchConfig, progress: bool
) -> tuple[DiffusionTranslator, dict[str, Any]]:
    """The checkpoint at ``path`` with the shipped inference defaults, or a small fresh fit."""
    defaults = DiffusionConfig().model_dump()
    overrides = cfg.translator_overrides.get("diffusion", {})
    if path:
        p = Path(path)
        if not p.exists():
            raise TactileBenchError(f"--diffusion {path}: no such checkpoint")
        model = (
            DiffusionTranslator.from_pretrained(p) if p.is_dir() else DiffusionTranslator.load(p)
        )
        saved = {k: getattr(model.config, k) for k in INFERENCE_KEYS}
        shipped = {k: defaults[k] for k in INFERENCE_KEYS} | overrides
        model.config = model.parse_config(model.config.model_dump() | shipped)
        return model.eval(), {"source": str(p), "checkpoint_inference_settings": saved}
    settings = {"max_steps": cfg.fit_steps, "lr": cfg.fit_lr, "seed": cfg.seed} | overrides
    model = DiffusionTranslator(settings)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tb_bench_fit_") as tmp:
        model.fit_pairs(
            finetune.depth,
            finetune.foreground("real"),
            Path(tmp),
            {"enable_progress_bar": progress},
        )
    info = {
        "source": "fitted by the bench (no --diffusion given)",
        "fit_steps": model.config.max_steps,
        "fit_pairs": len(finetune),
        "fit_s": time.perf_counter() - start,
    }
    return model.eval(), info


#: how a section runs inside ``run_bench``: announced, timed into ``section_wall_s``
_Step = Callable[[str, Callable[[], Any]], Any]


def run_bench(
    cfg: BenchConfig,
    out_dir: str | Path = ".",
    diffusion: str | None = None,
    braille: str | None = None,
    sections: tuple[str, ...] = SECTIONS,
    threads: int | None = None,
    progress: bool = True,
    command: str | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Run the chosen sections, write ``bench.json`` and ``bench.md`` in ``out_dir``.

    ``command`` is the command line to print in bench.md (the CLI passes its own).
    ``device`` other than ``cpu`` adds the ``device`` section: its rows on that device
    beside the CPU's.
    """
    _check_request(sections, diffusion, braille)
    accelerator = check_device(device)
    if accelerator.type != "cpu" and "device" not in sections:
        sections = (*sections, "device")
    started = time.perf_counter()
    result: dict[str, Any] = {
        "config": _jsonable(dataclasses.asdict(cfg)),
        "loadavg_start": _loadavg(),
        "sections": list(sections),
        "command": command,
    }
    with torch_threads(threads), _quiet_lightning():
        result["machine"] = machine_info()
        step = _timed_steps(result, progress)
        result["machine"]["conv_probe"] = step(
            "precision: conv fp32 vs bf16", lambda: conv_probe(cfg.conv_batch, cfg.repeats)
        )
        if "startup" in sections:
            result["startup"] = step(
                "start-up: --help of every command", lambda: startup.startup_times(cfg.repeats)
            )
        if "simulation" in sections:
            result["simulation"] = _simulation_section(step, cfg)
        needs_data = {"sampling", "threads", "training", "seeds", "scaling"} & set(sections)
        if needs_data:
            data = step("braille data", lambda: braille_data(braille, cfg, progress))
        if {"sampling", "threads"} & set(sections):
            _model_sections(step, result, cfg, sections, data, diffusion, progress)
        if {"training", "seeds", "scaling"} & set(sections):
            _training_sections(step, result, cfg, sections, data["finetune"], progress)
        if "device" in sections:
            sizes = DeviceBenchSizes.quick() if cfg.quick else DeviceBenchSizes()
            devices = [torch.device("cpu"), *([accelerator] if accelerator.type != "cpu" else [])]
            result["device"] = step(
                "sampling and training on " + ", ".join(str(d) for d in devices),
                lambda: device_rows(devices, sizes),
            )
        if "jpeg" in sections:
            result["jpeg"] = step(
                "JPEG codecs: ours, kornia's, libjpeg",
                lambda: jpeg.jpeg_section(
                    cfg.jpeg_images,
                    cfg.jpeg_native_images,
                    cfg.jpeg_qualities,
                    cfg.repeats,
                    cfg.seed,
                ),
            )
        if "diagnosis" in sections:
            result["diagnosis"] = _diagnosis_section(step, cfg, progress)
    result["loadavg_end"] = _loadavg()
    result["wall_s"] = round(time.perf_counter() - started, 1)
    out = Path(out_dir)
    atomic_write_json(out / "bench.json", _jsonable(result))
    atomic_write_text(out / "bench.md", render_markdown(result))
    return result


def _check_request(sections: tuple[str, ...], diffusion: str | None, braille: str | None) -> None:
    """Refuse unknown sections and missing inputs before minutes of measuring, not after."""
    known = [*SECTIONS, *OPTIONAL_SECTIONS]
    unknown = sorted(set(sections) - set(known))
    if unknown:
        raise TactileBenchError(f"--only: unknown sections {unknown}; known: {known}")
    for flag, path in (("--diffusion", diffusion), ("--braille", braille)):
        if path and not Path(path).exists():
            raise TactileBenchError(f"{flag} {path}: no such file or folder")


def _timed_steps(result: dict[str, Any], progress: bool) -> _Step:
    """One way to run every section: announced on the console, its wall time kept in result."""

    def step(name: str, fn: Callable[[], Any]) -> Any:
        if progress:
            print(f"[bench] {name} ...", flush=True)
        t0 = time.perf_counter()
        value = fn()
        result.setdefault("section_wall_s", {})[name] = round(time.perf_counter() - t0, 2)
        return value

    return step


def _simulation_section(step: _Step, cfg: BenchConfig) -> dict[str, Any]:
    """Braille contacts and object frames per second, with the full measurements beside."""
    braille_sim = step(
        "simulation: braille", lambda: simulation.braille(cfg.sim_contacts, cfg.repeats)
    )
    objects_sim = step(
        "simulation: objects", lambda: simulation.objects(cfg.sim_frames, cfg.repeats)
    )
    return {
        "braille_contacts_per_s": braille_sim["contacts_per_s"],
        "object_frames_per_s": objects_sim["frames_per_s"],
        "braille": braille_sim,
        "objects": objects_sim,
    }


def _diagnosis_section(step: _Step, cfg: BenchConfig, progress: bool) -> dict[str, Any]:
    """The gap diagnosis of ``cfg.diagnosis_pairs`` fresh pairs, as ``diagnose`` runs it."""
    return step(
        f"gap diagnosis of {cfg.diagnosis_pairs} pairs",
        lambda: diagnosis.diagnosis_row(
            cfg.diagnosis_pairs,
            cfg.diagnosis_size,
            cfg.seed,
            cfg.diagnosis_candidates,
            cfg.diagnosis_downstream,
            progress,
        ),
    )


def _model_sections(
    step: _Step,
    result: dict[str, Any],
    cfg: BenchConfig,
    sections: tuple[str, ...],
    data: dict[str, BrailleSet],
    diffusion: str | None,
    progress: bool,
) -> None:
    """Sampling and threads: both time the one diffusion model, loaded or fitted once here."""
    model, origin = step(
        "diffusion model",
        lambda: diffusion_translator(diffusion, data["finetune"], cfg, progress),
    )
    result.update(_sampling_section(step, cfg, model, origin, data["test"], progress))
    if "threads" in sections:
        result["threads"] = step(
            "threads and OpenMP wait policy",
            lambda: thread_settings(
                model, data["test"].subset(slice(0, cfg.variant_images)), cfg.repeats
            ),
        )
        result["threads_model"] = origin


def _sampling_section(
    step: _Step,
    cfg: BenchConfig,
    model: DiffusionTranslator,
    origin: dict[str, Any],
    test: BrailleSet,
    progress: bool,
) -> dict[str, Any]:
    """``sampling`` (the table's rows) and ``sampling_details`` (what the rows stand on)."""
    table = step(
        "sampling",
        lambda: sampling.sampling_table(
            model,
            test,
            [sampling.Case(*c) for c in cfg.cases],
            cfg.ddpm_images,
            cfg.repeats,
            cfg.default_images,
            seed=cfg.seed,
            progress=progress,
        ),
    )
    variants = step(
        "inference settings",
        lambda: sampling.inference_variants(
            model, test.subset(slice(0, cfg.variant_images)), cfg.repeats, cfg.seed
        ),
    )
    presets = step(
        "network presets",
        lambda: sampling.preset_speed(
            cfg.presets,
            cfg.preset_batch,
            model.config.image_size,
            cfg.repeats,
            model.config.precision,
        ),
    )
    return {
        "sampling": [*table["rows"], table["default_large"]],
        "sampling_details": {
            **{k: v for k, v in table.items() if k not in ("rows", "default_large")},
            "model": origin,
            "default": {k: getattr(model.config, k) for k in INFERENCE_KEYS}
            | {"compute_precision": model.inference_precision()},
            "default_check": default_check(table),
            "inference_variants": variants,
            "presets": presets,
        },
    }


def _training_sections(
    step: _Step,
    result: dict[str, Any],
    cfg: BenchConfig,
    sections: tuple[str, ...],
    finetune: BrailleSet,
    progress: bool,
) -> None:
    """Training throughput and epoch scaling: both train on the finetune set's real pairs."""
    fg, depth, labels = finetune.foreground("real"), finetune.depth, finetune.labels
    if "training" in sections:
        result["training"] = step(
            "training throughput",
            lambda: training.training_throughput(
                depth,
                fg,
                labels,
                cfg.train_warmup,
                cfg.train_steps,
                progress,
                cfg.translator_overrides,
            ),
        )
    if "seeds" in sections:
        result["seeds"] = step(
            "seeds in turn and batched",
            lambda: training.seed_batching(fg, labels, cfg.seed_images),
        )
    if "scaling" in sections:
        sim_scaling = {}
        if "simulation" in result:
            sim = result["simulation"]
            sim_scaling = {k: sim[k]["scaling"] for k in ("braille", "objects")}
        epochs = step(
            "epoch scaling",
            lambda: training.epoch_scaling(
                depth, fg, labels, cfg.epoch_sizes, cfg.translator_overrides
            ),
        )
        result["scaling"] = {
            "simulation": {
                k: {"rows": v, "linearity": simulation.linearity(v)} for k, v in sim_scaling.items()
            },
            "epoch": epochs,
        }


@contextmanager
def _quiet_lightning() -> Iterator[None]:
    """Dozens of short fits: keep Lightning's per-fit banners and hints off the console."""
    loggers = [logging.getLogger(n) for n in ("lightning.pytorch", "lightning.fabric")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            for message in (".*val_dataloader.*", ".*LeafSpec.*", ".*weights_only.*"):
                warnings.filterwarnings("ignore", message=message)
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def default_check(table: dict[str, Any]) -> dict[str, Any]:
    """Does the default sampler meet issue 8's targets, by how much, in this run?"""
    same = next(r for r in table["rows"] if r["default"])
    large = table["default_large"]
    checks = {
        "speedup_vs_ddpm500": (same["speedup_vs_ddpm500"], TARGET_SPEEDUP),
        "ssim_minus_ddpm500": (same["ssim_minus_ddpm500"], -TARGET_SSIM_DROP),
        "images_per_s": (large["images_per_s"], TARGET_IMAGES_PER_S),
    }
    return {k: {"value": v, "target": t, "met": bool(v >= t)} for k, (v, t) in checks.items()} | {
        "all_met": all(v >= t for v, t in checks.values())
    }


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float):
        return round(obj, 6)
    if isinstance(obj, torch.Tensor):
        return obj.tolist()
    return obj
