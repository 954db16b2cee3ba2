"""Property-based tests (Hypothesis) of the validation layer: any generated recipe text,
command line or paired folder either loads or raises TactileBenchError with a one-line
message; never another exception, never a hang (each example has a deadline, and the
memory limit is lowered so nothing accepted can plan a large allocation)."""

from __future__ import annotations

import resource
import tempfile
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from PIL import Image

from tactile_bench.cli import build_parser
from tactile_bench.cli_args import check_arguments
from tactile_bench.diagnose.paired import load_paired
from tactile_bench.errors import TactileBenchError
from tactile_bench.guard.limits import MEMORY_LIMIT_ENV
from tactile_bench.pipeline.recipe import load_recipe


def bounded(examples: int) -> settings:
    """Each example within 5 s; the same examples every run (a failure reproduces)."""
    return settings(
        max_examples=examples,
        deadline=timedelta(seconds=5),
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
        derandomize=True,
    )


#: how much the process's peak resident memory may grow over all examples of one test
MAX_RSS_GROWTH_MB = 512


@pytest.fixture(autouse=True)
def bounded_memory(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The guard's memory limit lowered (nothing accepted may plan more than 256 MB), and
    the peak RSS over the test's examples measured: no example may balloon."""
    monkeypatch.setenv(MEMORY_LIMIT_ENV, "256M")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    yield
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grown_mb < MAX_RSS_GROWTH_MB, f"peak RSS grew {grown_mb:.0f} MB"


def one_line(exc: TactileBenchError) -> None:
    message = str(exc)
    assert message and "\n" not in message and "Traceback" not in message, message
    event("refused")


# ----------------------------------------------------------------------------- recipes
KEYS = [
    "name",
    "seed",
    "stages",
    "trainer",
    "kind",
    "config",
    "inputs",
    "chars",
    "n_test",
    "n_classifier",
    "max_epochs",
    "seeds",
    "objects",
    "n_pairs",
    "image_size",
    "bogus",
]
scalar_text = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.sampled_from(
        [
            "sim_only",
            "braille_data",
            "report",
            "classify",
            "AB",
            "AAB",
            "ABC",
            "~",
            "null",
            ".nan",
            "-.inf",
            "1e400",
            "[1,",
            "{",
            "'x",
            "&a x",
            "*a",
            "*zz",
            "!!python/object:os.system",
            "<<: *a",
            "|",
            "? x",
            "---",
            "%",
        ]
    ),
    st.text(max_size=6),
)


TEMPLATE = """name: fuzz
seed: {seed}
trainer: {{{trainer}: {value}}}
stages:
  - {{name: a, kind: braille_data, config: &b {{chars: {chars}, n_test: {n}, n_finetune: 4}}}}
  - {{name: b, kind: braille_data, config: {{<<: *b, n_classifier: {n}}}}}
  - {{name: r, kind: report, inputs: {{rows: b}}}}
"""


@st.composite
def yaml_documents(draw: st.DrawFn) -> str:
    """YAML-ish text: mappings, lists, anchors, aliases, duplicate keys, broken syntax; a
    third of them a valid recipe with one value drawn at random."""
    if draw(st.integers(0, 2)) == 0:
        fields = {"seed": "0", "trainer": "max_epochs", "value": "1", "chars": "AB", "n": "4"}
        choices = {
            "seed": ["7", "-1", "4294967296", "x"],
            "trainer": ["max_epoch", "precision"],
            "value": ["0", "-1", "32"],
            "chars": ["ABC", "AAB", "A", "A!"],
            "n": ["0", "360", "793", "1000000000"],
        }
        key = draw(st.sampled_from(sorted(choices)))
        fields[key] = draw(st.sampled_from(choices[key]))
        return TEMPLATE.format(**fields)
    lines = ["name: fuzz"] if draw(st.booleans()) else []
    for _ in range(draw(st.integers(0, 12))):
        indent = "  " * draw(st.integers(0, 3))
        key = draw(st.sampled_from(KEYS))
        anchor = f" &{draw(st.sampled_from('ab'))}" if draw(st.integers(0, 5)) == 0 else ""
        value = draw(scalar_text)
        form = draw(st.integers(0, 4))
        if form == 0:
            lines.append(f"{indent}{key}:{anchor} {value}")
        elif form == 1:
            lines.append(f"{indent}- {key}:{anchor} {value}")
        elif form == 2:
            alias = draw(st.sampled_from("ab"))
            lines.append(f"{indent}{key}: [{', '.join([f'*{alias}'] * draw(st.integers(1, 9)))}]")
        elif form == 3:
            lines.append(f"{indent}{key}:{anchor}")
        else:
            lines.append(
                f"{indent}- {{name: s{draw(st.integers(0, 2))}, kind: "
                f"{draw(st.sampled_from(['braille_data', 'report', 'classify', 'x']))}, "
                f"config: {{{draw(st.sampled_from(KEYS))}: {value}}}}}"
            )
    return "\n".join(lines) + "\n"


@bounded(150)
@given(
    text=yaml_documents(), overrides=st.lists(scalar_text.map(lambda v: f"seed={v}"), max_size=1)
)
def test_any_recipe_text_loads_or_is_one_line_error(text: str, overrides: list[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzz.yaml"
        path.write_text(text)
        try:
            recipe = load_recipe(path, overrides)
        except TactileBenchError as exc:
            one_line(exc)
        else:
            assert 0 <= recipe.seed < 2**32 and recipe.stages
            event("loaded")


# ----------------------------------------------------------------------------- CLI arguments
NUMBERS = st.one_of(
    st.integers(-(2**40), 2**40).map(str),
    st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e30", "0.5", "", "x", "1_000"]),
)
COMMANDS = {
    "export-pairs": ["--generate", "--size", "--seed"],
    "diagnose": ["--seed", "--max-pairs", "--fit-fraction", "--size"],
    "data ycb-slide": ["--pairs", "--seed"],
    "validate-diagnosis": ["--pairs", "--size", "--seed"],
    "bench": ["--repeats", "--ddpm-images", "--seed"],
    "render": ["--seed"],
    "read": ["--model-seed", "--press-mm", "--step-mm", "--pitch-mm", "--seed"],
    "real-translators gelsight": ["--pretrain-pairs", "--pretrain-steps", "--cgan-steps"],
}


@bounded(200)
@given(
    command=st.sampled_from(sorted(COMMANDS)),
    data=st.data(),
    threads=st.none() | NUMBERS,
    out=st.sampled_from(["out", "f.txt", "f.txt/sub", "sheet.jpg", "sheet.png", "", "."]),
)
def test_any_command_line_is_accepted_or_one_line_error(
    command: str, data: st.DataObject, threads: str | None, out: str
) -> None:
    flags = data.draw(st.lists(st.sampled_from(COMMANDS[command]), max_size=3, unique=True))
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "f.txt").write_text("a file")
        (Path(tmp) / "pairs").mkdir()
        args = ["--threads", threads] if threads is not None else []
        args += command.split()
        args += ["pairs"] if command == "diagnose" else []
        args += ["--out", str(Path(tmp) / out)] if command != "read" else []
        for f in flags:
            args += [f, data.draw(NUMBERS)]
        try:
            ns = build_parser().parse_args(args)
        except SystemExit as exc:  # argparse: one "error:" line, exit 2
            assert exc.code == 2
            return
        try:
            check_arguments(ns)
        except TactileBenchError as exc:
            one_line(exc)
        else:
            event("accepted")


# ----------------------------------------------------------------------------- paired reader
CLEAN = {
    "pairs": [("a", "c0"), ("b", "c0"), ("", "c1")],
    "size": 16,
    "odd_size": False,
    "depth_max": 300,
    "depth_mode": "I;16",
    "real_mode": "RGB",
    "corrupt": None,
    "background": True,
    "missing_part": None,
    "gel": None,
}


@st.composite
def paired_folders(draw: st.DrawFn) -> dict:
    """Folders with one or more faults, or (a quarter) a clean one with one fault drawn."""
    if draw(st.integers(0, 3)) == 0:
        key = draw(st.sampled_from(["none", "depth_max", "real_mode", "gel", "size"]))
        values = {
            "none": [None],
            "depth_max": [0, 65000],
            "real_mode": ["P", "RGBA"],
            "gel": ['{"width_mm": 18, "height_mm": 24}', "{}"],
            "size": [20, 8],
        }
        return CLEAN | ({} if key == "none" else {key: draw(st.sampled_from(values[key]))})
    n = draw(st.integers(0, 3))
    size = draw(st.sampled_from([1, 8, 16, 20]))
    labels = draw(
        st.lists(
            st.sampled_from(["", "a", "A", "number_sign", "%23", ".", "x y"]),
            min_size=n,
            max_size=n,
        )
    )
    names = draw(
        st.lists(st.sampled_from(["c0", "C0", "c1", "é", "c0.PNG"]), min_size=n, max_size=n)
    )
    return {
        "pairs": list(zip(labels, names, strict=True)),
        "size": size,
        "odd_size": draw(st.booleans()) and n > 0,
        "depth_max": draw(st.sampled_from([0, 300, 2000, 65000])),
        "depth_mode": draw(st.sampled_from(["I;16", "L", "RGB"])),
        "real_mode": draw(st.sampled_from(["RGB", "RGBA", "L", "P"])),
        "corrupt": draw(st.sampled_from([None, "depth", "sim", "real", "background"])),
        "background": draw(st.booleans()),
        "missing_part": draw(st.sampled_from([None, "sim", "real"])),
        "gel": draw(
            st.sampled_from(
                [
                    None,
                    "{}",
                    '{"width_mm": 18, "height_mm": 24}',
                    '{"width_mm": -1, "height_mm": 1e9}',
                    "garbage",
                ]
            )
        ),
    }


def _write(folder: dict, root: Path) -> None:
    rng = np.random.default_rng(0)
    s = folder["size"]
    for i, (label, name) in enumerate(folder["pairs"]):
        for part in ("depth", "sim", "real"):
            if part == folder["missing_part"] and i == 0:
                continue
            d = root / part / label if label else root / part
            d.mkdir(parents=True, exist_ok=True)
            file = d / (name if name.lower().endswith(".png") else f"{name}.png")
            w = s + 1 if folder["odd_size"] and i == 0 and part == "real" else s
            if part == "depth":
                arr = np.full((s, s), folder["depth_max"], np.uint16)
                mode = folder["depth_mode"]
                im = Image.fromarray(arr) if mode == "I;16" else Image.new(mode, (s, s))
            else:
                im = Image.fromarray(rng.integers(0, 256, (s, w, 3), np.uint8))
                if part == "real" and folder["real_mode"] != "RGB":
                    im = im.convert(folder["real_mode"])
            im.save(file)
            if folder["corrupt"] == part:
                file.write_bytes(file.read_bytes()[:40])
    if folder["background"]:
        Image.new("RGB", (s, s), (90, 90, 90)).save(root / "background.png")
        if folder["corrupt"] == "background":
            (root / "background.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    if folder["gel"] is not None:
        (root / "gel.json").write_text(folder["gel"])


@bounded(120)
@given(folder=paired_folders())
def test_any_paired_folder_loads_or_is_one_line_error(folder: dict) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "pairs"
        root.mkdir()
        _write(folder, root)
        try:
            data = load_paired(root)
        except TactileBenchError as exc:
            one_line(exc)
        else:
            assert len(data) == len(folder["pairs"]) > 0
            assert data.size >= 16 and float(data.depth.max()) <= 5.0
            keys = {(lab, nam.casefold()) for lab, nam in zip(data.labels, data.names, strict=True)}
            assert len(keys) == len(data)  # no pair read twice
            event("loaded")
