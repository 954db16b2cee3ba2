"""YAML for recipes and profiles: regular files only, no alias bombs, no duplicate keys.

``yaml.safe_load`` builds shared objects for aliases, so a kilobyte of nested aliases
("billion laughs") is cheap to load but explodes as soon as anything copies or walks it;
and it keeps the last of two equal keys without a word. :func:`load_yaml_text` composes the
node graph first, counts the nodes it stands for (aliases expanded) and refuses more than
:data:`MAX_NODES`, recursive aliases, and a key written twice in one mapping, all before
building a single Python object.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml

from tactile_bench.errors import TactileBenchError

#: nodes a document may stand for once aliases are expanded (the largest shipped recipe: ~400)
MAX_NODES = 100_000
#: bytes a recipe or profile may have (the largest shipped one: ~5 KB)
MAX_BYTES = 1 << 20
_MERGE = "tag:yaml.org,2002:merge"


def read_regular_file(path: Path, what: str, max_bytes: int = MAX_BYTES) -> str:
    """The text of ``path`` if it is a regular file of at most ``max_bytes``.

    A FIFO, a device or a socket would block or never end; a folder is a user's slip.
    """
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise TactileBenchError(f"{path}: {what} file not found") from None
    except OSError as exc:
        raise TactileBenchError(f"{path}: cannot read {what} ({exc.strerror})") from None
    if stat.S_ISDIR(info.st_mode):
        raise TactileBenchError(f"{path}: is a folder, not a {what} file")
    if not stat.S_ISREG(info.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(info.st_mode) else "not a regular file"
        raise TactileBenchError(f"{path}: {kind}; a {what} must be a regular file")
    if info.st_size > max_bytes:
        raise TactileBenchError(
            f"{path}: {info.st_size} bytes; a {what} is at most {max_bytes} bytes"
        )
    try:
        with open(path, encoding="utf-8") as handle:
            return handle.read(max_bytes + 1)
    except (OSError, UnicodeDecodeError) as exc:
        raise TactileBenchError(f"{path}: cannot read {what} ({exc})") from None


def _check_graph(root: yaml.Node, where: str) -> None:
    """Count the expanded nodes under ``root``; refuse duplicates and recursion."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise TactileBenchError(f"{where}: a recursive alias (a node that contains itself)")
        active.add(key)
        total = 1
        if isinstance(node, yaml.MappingNode):
            seen: dict[tuple[str, str], int] = {}
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode) and key_node.tag != _MERGE:
                    ident = (key_node.tag, key_node.value)
                    if ident in seen:
                        raise TactileBenchError(
                            f"{where} line {key_node.start_mark.line + 1}: key "
                            f"{key_node.value!r} written twice in one mapping (first on line "
                            f"{seen[ident]})"
                        )
                    seen[ident] = key_node.start_mark.line + 1
                total += size(key_node) + size(value_node)
                if total > MAX_NODES:
                    break
        elif isinstance(node, yaml.SequenceNode):
            for child in node.value:
                total += size(child)
                if total > MAX_NODES:
                    break
        active.discard(key)
        sizes[key] = total
        if total > MAX_NODES:
            raise TactileBenchError(
                f"{where}: its aliases expand to more than {MAX_NODES} values (an alias bomb?)"
            )
        return total

    size(root)


def load_yaml_text(text: str, where: str) -> Any:
    """Parse one YAML document safely; any problem is a one-line error starting ``where``."""
    try:
        loader = yaml.SafeLoader(text)  # its reader already refuses control characters
    except yaml.YAMLError as exc:
        raise TactileBenchError(f"{where}: not valid YAML ({str(exc).splitlines()[0]})") from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_graph(node, where)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise TactileBenchError(f"{where}:{line} not valid YAML ({problem})") from None
    except RecursionError:
        raise TactileBenchError(f"{where}: nested too deeply") from None
    finally:
        loader.dispose()


def load_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """A recipe or profile file: :func:`read_regular_file`, then :func:`load_yaml_text`."""
    path = Path(path)
    return load_yaml_text(read_regular_file(path, what), str(path))
