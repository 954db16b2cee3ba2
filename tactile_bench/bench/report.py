"""bench.md: the figures of one ``bench`` run as tables, with what they mean."""

from __future__ import annotations

from typing import Any

from tactile_bench.bench.device import device_markdown

_PHASE_ORDER = {"depth": 0, "sim_image": 1, "real_image": 2}
NONLINEAR = 0.15  # |time(kx) / (k time(1x)) - 1| above this is called out as not linear


def _table(header: list[str], rows: list[list[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines + [""]


def _number(x: float | None, digits: int = 2) -> str:
    """``x`` to ``digits`` decimals (thousands grouped, no decimals); "-" for None."""
    if x is None:
        return "-"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.{digits}f}"


def _precision(row: dict[str, Any]) -> str:
    """``auto -> 32-true`` for a row that asked auto, else what it ran in (older bench.json
    files carry ``bf16: true/false`` instead)."""
    compute = row.get("compute_precision")
    if compute is None:
        return "bf16-mixed" if row.get("bf16") else "32-true"
    asked = row.get("precision", compute)
    return f"{asked} -> {compute}" if asked != compute else str(compute)


def _bf16_line(m: dict[str, Any]) -> str:
    """Whether this CPU has bf16 arithmetic, and what ``precision: auto`` therefore picks."""
    if "native_bf16" not in m:
        return "- bf16: not recorded (a bench.json from before `precision: auto`)"
    native = "yes" if m["native_bf16"] else "no (emulated, many times slower than fp32)"
    return (
        f"- bf16 arithmetic on this CPU ({m['cpu_capability']}): {native}; `precision: auto` "
        f"(the default of every config) runs {m['auto_precision']} here. Every bf16 figure "
        f"below holds for {m['cpu_capability']} only: AVX-512-BF16 and AMX CPUs run bf16 "
        "faster than fp32 (docs/results/code_figures.md)."
    )


def _conv_line(m: dict[str, Any]) -> list[str]:
    """The one-convolution answer to "is bf16 worth it here" (absent in older bench.json)."""
    probe = m.get("conv_probe")
    if not probe:
        return []
    return [
        f"- one 3x3 conv ({probe['shape']}, {probe['threads']} threads): fp32 "
        f"{probe['fp32_ms']:.0f} ms, bf16 autocast {probe['bf16_ms']:.0f} ms "
        f"({probe['bf16_over_fp32']:.2f}x the fp32 time)"
    ]


def _machine(r: dict[str, Any]) -> list[str]:
    m = r["machine"]
    quick = r["config"]["quick"]
    return [
        "# tactile_bench: benchmark of this machine",
        "",
        f"`{r.get('command') or 'python -m tactile_bench bench' + (' --quick' if quick else '')}`"
        f": {'quick' if quick else 'full'} run, {r['wall_s']:.0f} s in all.",
        "",
        f"- machine: {m['cpu']} ({m['cpu_capability']}), {m['cores']} cores "
        f"({m.get('cores_usable')} usable), torch {m['torch']} with {m['torch_threads']} "
        f"thread(s), diffusers {m['diffusers']}, lightning {m['lightning']}, "
        f"Python {m['python']}; LD_PRELOAD: `{m['ld_preload'] or 'none'}`; malloc: "
        f"{m.get('malloc', 'default')}",
        _bf16_line(m),
        *_conv_line(m),
        f"- load average (1, 5, 15 min) at start {r['loadavg_start']}, at end "
        f"{r['loadavg_end']}: above the core count means other processes shared the CPU "
        "and absolute figures are low; the ratios were measured side by side.",
        "- method: every figure is the median of several repetitions after a warm-up "
        "(one DDPM-500 chain is a single repetition of 500 network evaluations); "
        "'per CPU-s' divides by this process's CPU time, steadier than wall time on a busy "
        "machine; peak memory is the resident set size above its level at the start of "
        "the measurement, sampled every 2 ms from /proc/self/statm (tracemalloc would miss "
        "torch's C++ allocations, ru_maxrss never comes down).",
        "",
    ]


def _sampling(r: dict[str, Any]) -> list[str]:
    """The sampling section: every sampler's row, the default against its targets, why."""
    d = r["sampling_details"]
    ddpm = f"DDPM-{d['baseline']['steps']}"
    lines = [
        f"## Diffusion sampling: speed and quality against the paper's {ddpm}",
        "",
        f"Model: {d['model']['source']}. Every row samples the same network on the same "
        f"{d['test_images']} braille test contacts (chunks of {d['sample_batch_size']}, "
        "same seed); the last row runs the default on the larger set. SSIM and MSE against "
        "the real image of each contact, on 0..255 as the paper reports them; `texture` is "
        "mean |Laplacian| of the generated images over the real ones' (1 = as much fine "
        "structure and noise as the real frames; the denoised average scores below 1).",
        "",
    ]
    lines += _sampler_table(r["sampling"], ddpm)
    lines += _default_against_targets(r, ddpm)
    lines += _default_speed_sources(d, r["machine"]["cpu_capability"])
    return lines


def _sampler_table(samples: list[dict[str, Any]], ddpm: str) -> list[str]:
    """One row a sampler and step count: speed and quality against the DDPM baseline."""
    rows = []
    for s in samples:
        name = f"**{s['sampler']}**" if s["default"] else s["sampler"]
        rows.append(
            [
                name,
                s["steps"],
                s["images"],
                _number(s["images_per_s"], 3),
                _number(s["images_per_cpu_s"], 3),
                _number(s["speedup_vs_ddpm500"], 1),
                _number(s["cpu_speedup_vs_ddpm500"], 1),
                _number(s["ssim"], 4),
                f"{s['ssim_minus_ddpm500']:+.4f}",
                _number(s["mse"], 2),
                _number(s["texture"], 2),
                _number(s["evals_per_s"], 0),
            ]
        )
    return _table(
        [
            "sampler",
            "steps",
            "images",
            "img/s",
            "img/CPU-s",
            f"x {ddpm}",
            f"x {ddpm} (CPU)",
            "SSIM",
            f"SSIM - {ddpm}",
            "MSE",
            "texture",
            "net evals/s",
        ],
        rows,
    )


def _default_against_targets(r: dict[str, Any], ddpm: str) -> list[str]:
    """The default sampler's figures beside issue 8's targets, and why it is the default."""
    d = r["sampling_details"]
    base = r["sampling"][0]
    check = d["default_check"]
    default = d["default"]
    met = "met" if check["all_met"] else "NOT met"
    return [
        f"**Default** ({default['sampler']}, {default['steps']} steps, precision "
        f"{_precision(default)} on {r['machine']['cpu_capability']}, channels_last "
        f"{default['channels_last']}, chunks of {default['sample_batch_size']}): targets {met}.",
        "",
        f"- {_number(check['speedup_vs_ddpm500']['value'], 1)}x the images/s of {ddpm} "
        f"(target >= {check['speedup_vs_ddpm500']['target']:.0f}x); {ddpm} ran at "
        f"{_number(base['images_per_s'], 3)} img/s.",
        f"- SSIM {check['ssim_minus_ddpm500']['value']:+.4f} against {ddpm}'s "
        f"{_number(base['ssim'], 4)} (target: no lower than -0.01).",
        f"- {_number(check['images_per_s']['value'], 1)} images/s on the large set with "
        f"{r['machine']['torch_threads']} thread(s) at 64 x 64 (target >= 10; the paper: "
        "30 images in 23 s = 1.3 images/s on an RTX-3080).",
        "",
        *_why_default(r["sampling"], default, ddpm),
    ]


def _default_speed_sources(d: dict[str, Any], cpu_capability: str) -> list[str]:
    """The default's inference settings one at a time, then the network presets' speed."""
    variants = d["inference_variants"]
    steps = d["default"]["steps"]
    return [
        "### Where the default's speed comes from (same sampler, same contacts)",
        "",
        *_table(
            ["setting", "precision", "channels_last", "batch", "img/s", "img/CPU-s", "x default"],
            [
                [
                    v["variant"],
                    _precision(v),
                    v["channels_last"],
                    v["batch"],
                    _number(v["images_per_s"], 2),
                    _number(v["images_per_cpu_s"], 2),
                    _number(v["vs_default"], 2),
                ]
                for v in variants
            ],
        ),
        "### Network presets (random weights: speed only)",
        "",
        f"Precision: {_presets_precision(d['presets'])} on {cpu_capability}.",
        "",
        *_table(
            ["preset", "parameters", "net evals/s", "DDPM-500 img/s", f"{steps}-step img/s"],
            [
                [
                    name,
                    f"{p['params'] / 1e6:.2f} M",
                    _number(p["evals_per_s"], 1),
                    _number(p["ddpm500_images_per_s"], 4),
                    _number(p["evals_per_s"] / steps, 2),
                ]
                for name, p in d["presets"].items()
            ],
        ),
        "torch.compile is not used: its compile time outweighs its gain per network "
        "evaluation at these sizes (docs/results/code_figures.md).",
        "",
    ]


def _presets_precision(presets: dict[str, Any]) -> str:
    """What the preset rows ran in (older bench.json files: bf16, then the only choice)."""
    found = {p.get("compute_precision", "bf16-mixed") for p in presets.values()}
    return ", ".join(sorted(found)) or "-"


def _why_default(rows: list[dict[str, Any]], default: dict[str, Any], ddpm: str) -> list[str]:
    """The reasoning behind the default, with this run's figures."""
    base = rows[0]
    same = [r for r in rows if r.get("subset") == "ddpm500" and r is not base]
    ok = [r for r in same if r["ssim_minus_ddpm500"] >= -0.01]
    fastest = max(ok, key=lambda r: r["images_per_s"]) if ok else None
    solver = [r for r in same if r["sampler"] == default["sampler"]]
    lo = min((r["ssim"] for r in solver), default=float("nan"))
    hi = max((r["ssim"] for r in solver), default=float("nan"))
    text = (
        "Why this default: the network predicts x0 (the clean foreground), so each solver "
        "step is already a denoised estimate and a second-order multistep solver needs few "
        f"steps. In this run {default['sampler']} stays at SSIM {lo:.4f}-{hi:.4f} over "
        f"{', '.join(str(r['steps']) for r in solver)} steps ({ddpm}: {base['ssim']:.4f}, "
        f"texture {base['texture']:.2f}), while its cost grows with the number of network "
        "evaluations."
    )
    if fastest is not None:
        text += (
            f" The fastest row within 0.01 SSIM of {ddpm} is {fastest['sampler']} with "
            f"{fastest['steps']} step(s) ({fastest['speedup_vs_ddpm500']:.0f}x)."
        )
    text += (
        f" So more steps do not buy SSIM here; the default keeps {default['steps']} because "
        "from 3 steps on DPM-Solver++ takes second-order steps and still draws a sample "
        "(one step returns the network's x0 estimate from pure noise, a regression), at "
        "about twice the cost of 2 steps and well inside the targets. "
        "`translator_config: {steps: 1}` or `{steps: 2}` is faster still."
    )
    return [text, ""]


def _threads(r: dict[str, Any]) -> list[str]:
    rows = []
    for t in r["threads"]:
        if "error" in t:
            rows.append([t["setting"], "failed: " + t["error"], "-", "-", "-"])
            continue
        rows.append(
            [
                t["setting"],
                _number(t["images_per_s"], 2),
                _number(t["images_per_cpu_s"], 2),
                _number(t.get("vs_first"), 2),
                _number(t["ssim"], 4),
            ]
        )
    return [
        "## Threads and OpenMP wait policy (default sampler, fresh process each)",
        "",
        *_table(["setting", "img/s", "img/CPU-s", "x 1 thread", "SSIM"], rows),
        "GNU OpenMP lets idle worker threads spin before they sleep. When the other core is "
        "busy (another program, another job), the spinning thread competes with the work: "
        "compare the two 2-thread rows. `python -m tactile_bench` therefore sets "
        "`OMP_WAIT_POLICY=PASSIVE` unless the environment sets it; `--threads 1` is the "
        "other safe choice on a busy machine. `diagnose` and `validate-diagnosis` are the "
        "exception: their thousands of small ops lose more to waking sleeping threads than "
        "spinning costs (docs/results/code_figures.md), so they leave the runtime's default.",
        "",
    ]


def _phases(section: dict[str, Any], unit: str) -> list[str]:
    """The per-phase table; bench.json files written before the rename carry the phases
    under ``stages``, and the committed results are read as they are."""
    phases = section["phases"] if "phases" in section else section["stages"]
    rows = [
        [
            name,
            _number(s["per_s"], 0),
            _number(1000 * s["median_wall_s"] / s["work"], 3),
            f"{100 * s['share']:.0f} %",
            _number(s["peak_mib"], 1),
        ]
        for name, s in sorted(phases.items(), key=lambda kv: _PHASE_ORDER.get(kv[0], 9))
    ]
    return _table(["phase", f"{unit}/s", f"ms per {unit[:-1]}", "share", "peak MiB"], rows)


def _simulation(r: dict[str, Any]) -> list[str]:
    s = r["simulation"]
    b, o = s["braille"], s["objects"]
    return [
        "## Contact simulation",
        "",
        f"- braille: **{_number(s['braille_contacts_per_s'], 0)} contacts/s** end to end "
        f"(`render_braille_set`: depth + sim image + surrogate-real image, "
        f"{b['scaling']['4x']['work']:.0f} contacts, {_number(b['scaling']['4x']['per_cpu_s'], 0)} "
        f"per CPU-s); one-off height-field bank "
        f"{_number(b['setup_bank_s'], 2)} s.",
        f"- pretraining objects ({', '.join(o['objects'])}): "
        f"**{_number(s['object_frames_per_s'], 1)} frames/s** end to end "
        f"(`build_ycb_slide_standin`, shards written, {o['scaling']['4x']['work']:.0f} frames, "
        f"{_number(o['scaling']['4x']['per_cpu_s'], 1)} per CPU-s with the workers' CPU); "
        f"one-off scene (mesh, ray-casting scene, trajectory) {_number(o['setup_scene_s'], 2)} s"
        + (
            f"; worker start-up (spawn, imports: once a process, in an untimed first build "
            f"of {o['scaling']['1x']['work']:.0f} frames) {_number(o['first_build_s'], 1)} s; "
            f"marginal rate of the frames a bigger build adds (2x -> 4x, fixed costs cancel) "
            f"{_number(o['marginal']['frames_per_s'], 1)} frames/s, "
            f"{_number(o['marginal']['frames_per_cpu_s'], 1)} per CPU-s"
            if "marginal" in o
            else ""
        )
        + ".",
        "",
        f"Braille, cost per phase ({b['contacts']} contacts):",
        "",
        *_phases(b, "contacts"),
        f"Objects, cost per phase ({o['frames']} frames; depth settles the press on the "
        "true and on the measured pose, as the builder does):",
        "",
        *_phases(o, "frames"),
    ]


def _training(r: dict[str, Any]) -> list[str]:
    t = r["training"]
    m = r["machine"]
    cap = m["cpu_capability"]
    auto = m.get("auto_precision")
    order = ("fp32", "bf16", "fp32+channels_last", "bf16+channels_last")
    seen = list(next(iter(t.values())))
    variants = [v for v in order if v in seen] + [v for v in seen if v not in order]
    rows = []
    for model, row in t.items():
        cells = [model]
        for v in variants:
            rate, speedup = row[v]["images_per_s"], row[v]["speedup_vs_fp32"]
            cells.append(f"{_number(rate, 1)} ({_number(speedup, 2)}x)")
        cells.append(_number(max(row[v]["peak_mib"] for v in variants), 0))
        rows.append(cells)

    def label(variant: str) -> str:
        """bf16 columns name the CPU capability they hold for; auto's precision is marked."""
        bf16 = variant.startswith("bf16")
        text = f"{variant} on {cap}" if bf16 else variant
        if auto is not None and bf16 == (auto == "bf16-mixed"):
            text += " (auto)"
        return text

    picks = (
        f"`precision: auto` trains in {auto} on this {cap} CPU, so the columns marked (auto) "
        "are what recipes get. "
        if auto is not None
        else ""
    )
    return [
        "## Training throughput (images/s of optimiser steps; x fp32 in brackets)",
        "",
        *_table(["model", *[label(v) for v in variants], "peak MiB"], rows),
        f"All figures measured on {cap}. {picks}bf16 = `precision='bf16-mixed'` (autocast): "
        "its x fp32 holds for this CPU capability only (without AVX-512-BF16 or AMX bf16 is "
        "emulated: far below 1x; with them above 1x, docs/results/code_figures.md). "
        "channels_last = weights converted once, activations follow. Medians over the "
        "timed steps after warm-up steps.",
        "",
    ]


def _seeds(r: dict[str, Any]) -> list[str]:
    rows = [
        [
            name,
            f"{row['seeds']} x {row['images']} images x {row['epochs']} epoch(s)",
            _number(row["in_turn_s"], 1),
            _number(row["batched_s"], 1),
            f"{_number(row['speedup'], 2)}x",
        ]
        for name, row in r["seeds"].items()
    ]
    return [
        "## A classify stage's seeds: one after another and as one batched model",
        "",
        *_table(["settings", "work", "in turn (s)", "batched (s)", "speed-up"], rows),
        f"Measured on {r['machine']['cpu_capability']}. Wall seconds of whole trainings "
        "(`train_classifier` per seed against `train_classifiers`, the `classify` stage's "
        "`batch_seeds: true`), each recipe's classifier settings, the default precision.",
        "",
    ]


def _scaling(r: dict[str, Any]) -> list[str]:
    sc = r["scaling"]
    lines = [
        "## Cost against work (1x, 2x, 4x)",
        "",
        "`linearity` = time at k x the work / (k x time at 1x): 1.00 is linear. Epochs "
        "train through the recipes' entry points with their defaults, so in `precision: "
        f"auto` ({r['machine'].get('auto_precision', 'not recorded')} here).",
        "",
    ]
    rows, notes = [], []
    for name, block in sc.get("simulation", {}).items():
        for key, row in block["rows"].items():
            lin = block["linearity"][key]
            rows.append(
                [
                    f"simulation: {name}",
                    key,
                    _number(row["work"], 0),
                    _number(row["median_wall_s"], 2),
                    _number(row["per_s"], 1),
                    _number(lin, 2),
                    _number(row["peak_mib"], 0),
                ]
            )
            if abs(lin - 1) > NONLINEAR:
                notes.append(f"simulation {name} at {key}: linearity {lin:.2f}")
    for name, block in sc["epoch"].items():
        for key, row in block.items():
            lin = row["linearity"]
            rows.append(
                [
                    f"one epoch: {name}",
                    key,
                    row["images"],
                    _number(row["epoch_s"], 2),
                    _number(row["images_per_s"], 1),
                    _number(lin, 2),
                    _number(row["peak_mib"], 0),
                ]
            )
            if abs(lin - 1) > NONLINEAR:
                notes.append(f"epoch {name} at {key}: linearity {lin:.2f}")
    lines += _table(["work", "scale", "items", "seconds", "items/s", "linearity", "peak MiB"], rows)
    if notes:
        lines += [
            "Not linear (more than 15 % off): " + "; ".join(notes) + ". Below 1 means the "
            "small run carries a fixed cost (start-up, warm-up of kernels and allocator, "
            "per-object scene set-up) that larger runs spread out; above 1 that the cost per "
            "item grows with the work.",
            "",
        ]
    else:
        lines += ["Every row is within 15 % of linear.", ""]
    return lines


def _startup(r: dict[str, Any]) -> list[str]:
    st = r["startup"]
    verdict = "met" if st["met"] else "NOT met"
    lines = [
        "## Command-line start-up",
        "",
        f"Each command in a fresh interpreter, median of {len(st['rows'][0]['runs_s'])} "
        f"runs. Every `--help` under {st['target_help_s']:g} s: {verdict} (slowest "
        f"{_number(st['slowest_help_s'], 2)} s). `list effects` loads torch, for scale.",
        "",
    ]
    rows = [[f"`{row['command']}`", _number(row["median_s"], 2)] for row in st["rows"]]
    return lines + _table(["command", "wall s"], rows)


def _jpeg(r: dict[str, Any]) -> list[str]:
    """Ours against kornia's differentiable JPEG, libjpeg the reference (issue 20)."""
    j = r["jpeg"]
    fr = j["frames"]
    settings = "; ".join(f"`{k}`: {v['what']}" for k, v in j["settings"].items())
    lines = [
        "## JPEG codecs: ours against kornia's, libjpeg the reference",
        "",
        f"Frames: {fr['source']} ({fr['stored']} stored, {fr['native']} native). Settings: "
        f"{settings}. Ours is `jpeg_approx`, kornia's `jpeg_codec_differentiable` "
        f"{j['kornia']} (0..1 in, scaled from 0..255), libjpeg Pillow's encode and decode; "
        "in the `effect` setting kornia and libjpeg get the same bilinear upsampling and "
        f"area averaging that ours folds into its matrices. {j['kornia_padding']}. "
        f"Ours and kornia's run in chunks of {j['chunk']} images with {j['threads']} torch "
        "thread(s), libjpeg frame by frame on one; img/s are medians of "
        f"{j['repeats']} repetition(s) after a warm-up. Errors are of each codec's output "
        "against libjpeg's on the same frames, in grey levels 0..255 (MAE) and dB (PSNR); "
        "`MAE vs input` is how far the codec moves the frame, libjpeg's being the scale "
        "to judge the others' errors by.",
        "",
    ]
    rows = [
        [
            f"`{row['setting']}`",
            row["quality"],
            row["codec"],
            _number(row["images_per_s"], 1),
            _number(row["fwd_bwd_images_per_s"], 1),
            _number(row["mae_vs_libjpeg"], 3),
            "identical" if row["psnr_vs_libjpeg"] is None else _number(row["psnr_vs_libjpeg"], 1),
            _number(row["max_abs_vs_libjpeg"], 1),
            _number(row["mae_vs_input"], 2),
        ]
        for row in j["rows"]
    ]
    lines += _table(
        [
            "setting",
            "quality",
            "codec",
            "img/s fwd",
            "img/s fwd+bwd",
            "MAE vs libjpeg",
            "PSNR vs libjpeg (dB)",
            "max abs vs libjpeg",
            "MAE vs input",
        ],
        rows,
    )
    verdicts = j.get("verdicts", {})
    if j.get("headline") in verdicts:
        lines += [f"**Verdict** (`{j['headline']}` setting): {verdicts[j['headline']]}", ""]
    others = [f"- `{k}`: {v}" for k, v in verdicts.items() if k != j.get("headline")]
    return lines + ([*others, ""] if others else [])


def render_markdown(r: dict[str, Any]) -> str:
    """The whole bench.md for a result dict of ``run_bench``."""
    lines = _machine(r)
    if "startup" in r:
        lines += _startup(r)
    if "sampling" in r:
        lines += _sampling(r)
    if "threads" in r:
        lines += _threads(r)
    if "simulation" in r:
        lines += _simulation(r)
    if "training" in r:
        lines += _training(r)
    if "seeds" in r:
        lines += _seeds(r)
    if "scaling" in r:
        lines += _scaling(r)
    if "jpeg" in r:
        lines += _jpeg(r)
    if "device" in r:
        lines += device_markdown(r["device"])
    if "diagnosis" in r:
        from tactile_bench.bench.diagnosis import diagnosis_markdown  # loads the diagnosis

        lines += diagnosis_markdown(r["diagnosis"])
    return "\n".join(lines).rstrip() + "\n"
