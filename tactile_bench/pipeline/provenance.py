"""What a run was made of, for ``run.json``: seeds, versions, platform, input and output hashes.

Two runs with the same recipe, seed, versions and input hashes on the same machine give the
same table (tests/test_reliability_resume.py checks it); ``run.json`` records all of those, so
a table can be traced to what made it, and a difference to its cause.

User files a recipe names (a YCB-Slide folder, a profile YAML, a translator checkpoint) are
found by looking at every string of every stage config that looks like a path and exists.
Their content hash also enters the stage's cache key, so editing a file reruns the stage
instead of silently reusing a result built from the old content. Hashes of large folders are
cached by (size, mtime) in ``<run dir>/.input_hashes.json``, so a rerun only stats them.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import importlib.metadata
import json
import logging
import os
import platform
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import tactile_bench
from tactile_bench.hardware import machine_compute
from tactile_bench.io import atomic_write_json, file_sha256

log = logging.getLogger("tactile_bench")

#: the project's key dependencies, recorded with their versions
PACKAGES = (
    "torch",
    "lightning",
    "torchmetrics",
    "diffusers",
    "kornia",
    "numpy",
    "scipy",
    "pydantic",
    "trimesh",
    "pillow",
)
CACHE = ".input_hashes.json"


def versions() -> dict[str, str | None]:
    """Python, the project and its key dependencies (None when not installed)."""
    out: dict[str, str | None] = {
        "python": platform.python_version(),
        "tactile_bench": tactile_bench.__version__,
    }
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def machine() -> dict[str, Any]:
    """Where the run happened: floating-point results can differ across CPUs and threads,
    and ``precision: auto`` picks bf16 or fp32 by the CPU (``cpu_capability``,
    ``native_bf16``, ``auto_precision``: see ``hardware``)."""
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_count": os.cpu_count(),
        "executable": sys.executable,
        **machine_compute(),  # cpu_capability, native_bf16, torch_threads, auto_precision
    }


def _strings(value: Any) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from _strings(v)
    elif isinstance(value, list | tuple):
        for v in value:
            yield from _strings(v)


class InputHasher:
    """Content hashes of the user files and folders stage configs name (cached by stat)."""

    def __init__(self, run_dir: Path, recipe_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self.recipe_dir = Path(recipe_dir)
        self.inputs: dict[str, dict[str, Any]] = {}
        try:
            self._cache: dict[str, Any] = json.loads((self.run_dir / CACHE).read_text())
            if not isinstance(self._cache, dict):
                self._cache = {}
        except (OSError, ValueError):
            self._cache = {}

    def resolve(self, text: str) -> Path | None:
        """The existing file or folder a config string names, or None if it is not a path.

        Only strings with a separator or a suffix count ("digit" is a profile name, not a
        path); relative paths are tried against the recipe's folder, then the working one.
        """
        if not text or "\n" in text or len(text) > 4096:
            return None
        path = Path(text).expanduser()
        if os.sep not in text and "/" not in text and not path.suffix:
            return None
        candidates = [path] if path.is_absolute() else [self.recipe_dir / path, Path.cwd() / path]
        for candidate in candidates:
            try:
                if candidate.exists():
                    return candidate.resolve()
            except OSError:
                continue
        return None

    def _file(self, path: Path) -> str:
        stat = path.stat()
        key = str(path)
        hit = self._cache.get(key)
        if hit and hit.get("size") == stat.st_size and hit.get("mtime_ns") == stat.st_mtime_ns:
            return str(hit["sha256"])
        digest = file_sha256(path)
        self._cache[key] = {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns, "sha256": digest}
        return digest

    def hash_path(self, path: Path) -> dict[str, Any]:
        """``{"sha256", "files", "bytes"}`` of a file, or of a folder's files and their names."""
        if path.is_file():
            return {"sha256": self._file(path), "files": 1, "bytes": path.stat().st_size}
        digest = hashlib.sha256()
        files = size = 0
        for file in sorted(p for p in path.rglob("*") if p.is_file()):
            rel = file.relative_to(path).as_posix()
            digest.update(f"{rel}\0{self._file(file)}\n".encode())
            files += 1
            size += file.stat().st_size
        return {"sha256": digest.hexdigest(), "files": files, "bytes": size}

    def config_files(self, config: Any) -> dict[str, str]:
        """``{string as written: sha256}`` for every path a stage config names."""
        found: dict[str, str] = {}
        for text in _strings(config):
            path = self.resolve(text)
            if path is None:
                continue
            entry = self.inputs.get(str(path))
            if entry is None:
                entry = self.inputs[str(path)] = self.hash_path(path)
            found[text] = entry["sha256"]
        self.save()
        return found

    def save(self) -> None:
        """Keep the stat cache for the next run (best effort: it is only a cache)."""
        try:
            atomic_write_json(self.run_dir / CACHE, self._cache)
        except OSError as exc:
            log.debug("could not write %s: %s", self.run_dir / CACHE, exc)


def _seeds(value: Any, where: str = "") -> dict[str, Any]:
    found: dict[str, Any] = {}
    if isinstance(value, dict):
        for key, v in value.items():
            here = f"{where}.{key}" if where else str(key)
            if key in ("seed", "seeds"):
                found[here] = v
            else:
                found |= _seeds(v, here)
    return found


def run_record(recipe: Any, results: list[Any], hasher: InputHasher) -> dict[str, Any]:
    """The content of ``run.json``."""
    stages = []
    seeds: dict[str, Any] = {"recipe": recipe.seed}
    for result in results:
        try:
            manifest = json.loads((result.directory / "_done.json").read_text())
        except (OSError, ValueError):
            manifest = {}
        config = manifest.get("config", {})
        seeds |= {f"{result.name}.{k}": v for k, v in _seeds(config).items()}
        stages.append(
            {
                "name": result.name,
                "kind": result.kind,
                "directory": result.directory.name,
                "config": config,
                "outputs": manifest.get("outputs", {}),
                "wall_time_s": result.wall_time_s,
                "peak_rss_mib": result.peak_rss_mib,
                "cached": result.cached,
                "resumed_from_step": result.metrics.get("resumed_from_step"),
                "compute_precision": result.metrics.get("compute_precision"),
                "processes": int(result.metrics.get("processes") or 1),
            }
        )
    recipe_path = Path(recipe.path)
    return {
        "recipe": str(recipe_path),
        "recipe_sha256": file_sha256(recipe_path) if recipe_path.is_file() else None,
        "name": recipe.name,
        "seed": recipe.seed,
        "seeds": seeds,
        "trainer": recipe.trainer,
        "versions": versions(),
        "machine": machine(),
        "inputs": hasher.inputs,
        "finished_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "stages": stages,
    }
