"""The code version of a result: a hash of the repository's source files that compute it.

A cache keyed on a model's hash alone survives a change to the data generator or the scoring and
hands back numbers the code no longer makes. Here the key covers every gprbot/ and training/ module a
root module imports, directly or through others (found by reading their import statements, so imports
inside functions count too), plus any data files named.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("gprbot", "training", "validation")


def _module_file(name: str) -> Path | None:
    """The source file of a repository module (a package's __init__.py), or None when it is not one."""
    if name.split(".")[0] not in PACKAGES:
        return None
    base = ROOT.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _imports(path: Path, module: str) -> set[str]:
    """The modules a source file imports (absolute and relative; `from a import b` names a and a.b)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def source_closure(roots: Iterable[str]) -> list[Path]:
    """The repository source files the root modules import, transitively, sorted."""
    seen: dict[str, Path] = {}
    todo = list(roots)
    while todo:
        name = todo.pop()
        path = _module_file(name)
        if path is None or name in seen:
            continue
        seen[name] = path
        todo.extend(_imports(path, name))
        parent = name.rpartition(".")[0]
        if parent:
            todo.append(parent)  # importing a.b runs a/__init__.py too
    return sorted(set(seen.values()))


def code_version(roots: Iterable[str], files: Iterable[Path] = ()) -> str:
    """A 16-hex-digit hash of the root modules' source closure and the named files (paths and bytes)."""
    digest = hashlib.sha256()
    for path in [*source_closure(roots), *sorted(Path(f) for f in files)]:
        digest.update(str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path).encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]
