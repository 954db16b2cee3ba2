"""The package imports one way (docs/architecture.md): no module imports another that
imports it back, counting imports inside functions too, and the layers import only the
layers below them (issue 20). Read from the source with ``ast``: nothing is imported.

Two kinds of edge load a module without an import statement, and count as imports: a
string naming a package module (``importlib.import_module("tactile_bench.x")``, a list of
command modules), and an entry point of ``pyproject.toml``, an edge from the module that
holds its group's name (the loader, e.g. ``translators.registry``) to the module it names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tactile_bench"

#: layers from the bottom up; a module may import its own layer and those below it. The
#: longest matching prefix decides (``diagnose.commands`` is above ``diagnose``).
LAYERS: tuple[tuple[str, ...], ...] = (
    (
        "",
        "errors",
        "io",
        "hardware",
        "allocator",
        "console",
        "pools",
        "guard",
    ),  # "": the package itself
    ("geometry",),
    ("effects", "metrics"),
    ("sensor",),
    ("data",),
    ("training",),
    ("translators",),
    ("classify",),
    ("diagnose", "report", "calibrate"),
    # the application: commands, recipes, benchmarks, the checks every command goes through
    (
        "pipeline",
        "bench",
        "read",
        "real_presses",
        "testing",
        "check",
        "diagnose.commands",
        "diagnose.validate",
        "calibrate.commands",
    ),
    ("cli", "cli_args", "__main__"),
)

#: edges against the flow that are known and named here, so the list can only shrink
KNOWN_UPWARD: dict[tuple[str, str], str] = {
    # the calibrated translator is the diagnosis's selected effects as a fitted simulator:
    # it is built on diagnose.candidates, .which and .run, so in translators/ it would import
    # them upwards; the registry loads it through its entry point like a plugin's
    ("translators.registry", "diagnose.calibrated"): "entry point `calibrated`",
}


def _modules() -> dict[str, Path]:
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _entry_points() -> dict[str, list[str]]:
    """{entry-point group: the modules its entries name} from ``pyproject.toml``."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    return {
        group: [target.partition(":")[0] for target in entries.values()]
        for group, entries in project.get("entry-points", {}).items()
    }


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """{module: package modules it imports anywhere in its file} (names without the
    ``tactile_bench.`` prefix; ``from pkg import submodule`` counts as the submodule; a
    string naming a module, and an entry point from its group's loader, count too)."""
    graph: dict[str, set[str]] = {}
    groups = _entry_points()
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                # an entry-point group's name (its loader), else "pkg.module[:name]"
                targets = groups.get(node.value, [node.value.partition(":")[0]])
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = ["tactile_bench", *package.split(".")] if package else ["tactile_bench"]
                    base = base[: len(base) - (node.level - 1)]
                    module = ".".join([*base, *([node.module] if node.module else [])])
                else:
                    module = node.module or ""
                # ``from pkg import sub`` imports the module ``pkg.sub``; ``pkg`` itself
                # counts only when a name is not a submodule
                subs = [f"{module}.{a.name}" for a in node.names]
                known = [s for s in subs if _short(s) in modules]
                targets = known + ([module] if len(known) < len(subs) else [])
            for target in targets:
                short = _short(target)
                if short is not None and short in modules and short != name:
                    found.add(short)
        graph[name] = found
    return graph


def _short(module: str) -> str | None:
    """``tactile_bench.data.corpus`` -> ``data.corpus``; None outside the package."""
    if module == "tactile_bench":
        return ""
    return module.removeprefix("tactile_bench.") if module.startswith("tactile_bench.") else None


def _layer(module: str) -> int:
    best = (-1, -1)
    for rank, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or (prefix and module.startswith(prefix + ".")) or prefix == "":
                best = max(best, (len(prefix), rank))
    return best[1]


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_even_through_imports_inside_functions() -> None:
    assert _cycles(_imports(_modules())) == []


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_every_module_has_a_layer() -> None:
    assert [m for m in _modules() if _layer(m) < 0] == []


def test_strings_and_entry_points_count_as_imports() -> None:
    graph = _imports(_modules())
    assert "diagnose.calibrated" in graph["translators.registry"]  # pyproject's entry point
    assert "diagnose.commands" in graph["cli"]  # cli.COMMAND_MODULES, imported by name
    named = [_short(target) for targets in _entry_points().values() for target in targets]
    assert named and all(target in _modules() for target in named)


def test_layers_import_only_downwards() -> None:
    graph = _imports(_modules())
    upward = sorted(
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if _layer(target) > _layer(module)
    )
    unexplained = [edge for edge in upward if edge not in KNOWN_UPWARD]
    assert unexplained == [], "imports against the flow of docs/architecture.md"
    fixed = [edge for edge in KNOWN_UPWARD if edge not in upward]
    assert fixed == [], "no longer against the flow: drop them from KNOWN_UPWARD"
