"""The ``bench`` subcommand: measure this machine and write bench.json and bench.md."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def _cmd_bench(ns: argparse.Namespace) -> int:
    from tactile_bench.bench.run import SECTIONS, BenchConfig, run_bench

    overrides: dict[str, Any] = {"seed": ns.seed}
    if ns.repeats is not None:
        overrides["repeats"] = ns.repeats
    if ns.ddpm_images is not None:
        overrides["ddpm_images"] = ns.ddpm_images
    cfg = BenchConfig.quick_preset(**overrides) if ns.quick else BenchConfig.full(**overrides)
    result = run_bench(
        cfg,
        out_dir=ns.out,
        diffusion=ns.diffusion,
        braille=ns.braille,
        sections=tuple(ns.only or SECTIONS),
        progress=not ns.no_progress,
        command=" ".join(["python -m tactile_bench", *sys.argv[1:]]),
        device=ns.device,
    )
    print(f"\nwrote {ns.out}/bench.json and {ns.out}/bench.md ({result['wall_s']:.0f} s)")
    if "sampling_details" in result:
        check = result["sampling_details"]["default_check"]
        print("default sampler targets " + ("met" if check["all_met"] else "NOT met") + ":")
        for key, c in check.items():
            if key != "all_met":
                print(
                    f"  {key:<20} {c['value']:10.4f}  target >= {c['target']:g}  "
                    + ("ok" if c["met"] else "MISSED")
                )
    return 0


class _Only(argparse.Action):
    """``--only``: the sections; ``--only diagnosis`` alone also keeps the environment's
    OpenMP wait policy, as ``diagnose`` does (``diagnose.commands.KEEP_OMP_WAIT_POLICY``),
    so that the figures are those of the command. With other sections the bench's
    ``PASSIVE`` stays (bench.md names the policy the diagnosis ran under)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        from tactile_bench.diagnose.commands import KEEP_OMP_WAIT_POLICY

        setattr(namespace, self.dest, values)
        if values and set(values) == {"diagnosis"}:
            namespace.omp_wait_policy = KEEP_OMP_WAIT_POLICY


def register(subparsers: Any) -> None:
    """Add ``bench`` to the CLI."""
    p = subparsers.add_parser(
        "bench",
        help="measure simulation, diffusion sampling and training on this machine",
        description="Write bench.json and bench.md: --help of every command in a fresh "
        "process, simulation contacts/s, a sampler speed/"
        "quality table against the paper's DDPM-500, training throughput (fp32 / bf16 / "
        "channels_last), cost at 1x/2x/4x work, peak memory, our differentiable JPEG against "
        "kornia's (libjpeg the reference). Use the global --threads to "
        "pin torch threads (default: torch's choice).",
    )
    p.add_argument("--quick", action="store_true", help="smaller samples: under 5 minutes")
    p.add_argument(
        "--diffusion",
        metavar="PATH",
        help="a fitted diffusion translator (translator.pt or a save_pretrained folder); "
        "without it the bench fits a small one first",
    )
    p.add_argument(
        "--braille",
        metavar="PATH",
        help="a braille_data stage folder (test.npz, finetune.npz) or a test.npz; "
        "without it the bench simulates the sets (same seed, same contacts)",
    )
    p.add_argument("--out", default=".", help="folder for bench.json and bench.md")
    p.add_argument(
        "--only",
        nargs="*",
        action=_Only,
        metavar="SECTION",
        help="startup, simulation, sampling, threads, training, seeds, scaling, jpeg, device, "
        "diagnosis (default: all but device and diagnosis; the simulation's 1x/2x/4x rows "
        "come with simulation; diagnosis: the gap diagnosis of 300 fresh pairs, 60 with "
        "--quick, timed span by span)",
    )
    p.add_argument(
        "--device",
        default="cpu",
        help="also time sampling and training on this device (cuda, cuda:1) beside the CPU: "
        "images/s, peak device memory, GPU busy share (the device section)",
    )
    p.add_argument("--repeats", type=int, help="timed repetitions per figure")
    p.add_argument("--ddpm-images", type=int, help="test contacts sampled by DDPM-500")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_bench)
