"""The package layering: imports run one way, with no cycles, and the simulated world stays a leaf.

The allowed layering is the data below (LAYERS); everything else is derived from the source with `ast`,
so a new module, a new cycle or an upward import fails here with the edge that caused it. Imports under
`if TYPE_CHECKING:` count for the layering (a type from an upper layer is still an upward dependency)
but not for cycles (they never run).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "gprbot"

# Bottom to top. A module belongs to the longest prefix listed; a module may import its own group and any
# group of a lower layer, never one of its own layer or above. Change this table on purpose, in review.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("gprbot", "gprbot.errors")),
    ("foundation", ("gprbot.backoff", "gprbot.atomic_files", "gprbot.progress", "gprbot.shutdown_budget",
                    "gprbot.sdnotify", "gprbot.config_ranges")),
    ("types", ("gprbot.config", "gprbot.messages", "gprbot.plotting")),
    # Physics and geometry that the simulated world and the robot's stages both stand on: pure numpy.
    ("models", ("gprbot.geometry", "gprbot.gpr.traveltime", "gprbot.gpr.wavelet", "gprbot.motion.kinematics",
                "gprbot.motion.planner")),
    ("world", ("gprbot.sim", "gprbot.runlog", "gprbot.shell", "gprbot.drivers", "gprbot.systemd_unit",
               "gprbot.motion", "gprbot.gpr")),
    ("stages", ("gprbot.fusion", "gprbot.runlog_reader", "gprbot.reconstruct", "gprbot.supervisor")),
    ("assembly", ("gprbot.survey", "gprbot.retention", "gprbot.exports", "gprbot.outputs")),
    ("inference", ("gprbot.infer",)),
    ("simulated", ("gprbot.simulated",)),
    ("robot", ("gprbot.robot",)),
    ("frontends", ("gprbot.web",)),
    ("daemon", ("gprbot.daemon",)),
    ("apps", ("gprbot.apps",)),
    ("cli", ("gprbot.cli",)),
    ("main", ("gprbot.__main__",)),
)

MODELS = [name for name, _ in LAYERS].index("models")

# The simulated world is imported only by the simulated robot, its offline pipeline and the entry points
# that run it (training/ and validation/ are outside the package and free to).
SIM_USERS = ("gprbot.sim", "gprbot.simulated", "gprbot.apps", "gprbot.cli")

# Edges being removed by the redesign; each must still exist (so the list only shrinks) and none may be new.
KNOWN_UPWARD: frozenset[tuple[str, str]] = frozenset()


@dataclass(frozen=True)
class Edge:
    """One import: importer module, imported module, whether it only runs under TYPE_CHECKING."""

    source: str
    target: str
    type_only: bool
    line: int


def module_name(path: Path) -> str:
    """The dotted module name of a file under the repository."""
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _type_checking_lines(tree: ast.Module) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if path.name != "__init__.py":
        base = base[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def import_edges(modules: dict[str, Path]) -> Iterator[Edge]:
    """Every import of a gprbot module by a gprbot module, lazy ones included."""
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        typed = _type_checking_lines(tree)
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(module, path, node)
                targets = [base]
                targets += [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules]
            for target in targets:
                if target.split(".")[0] == "gprbot" and target != module:
                    yield Edge(module, _owner(target, modules), node.lineno in typed, node.lineno)


def _owner(target: str, modules: dict[str, Path]) -> str:
    while target not in modules and "." in target:
        target = target.rsplit(".", 1)[0]
    return target


def group_of(module: str) -> tuple[int, str]:
    """(layer index, group prefix) of a module: the longest prefix in LAYERS."""
    best: tuple[int, str] | None = None
    for rank, (_, groups) in enumerate(LAYERS):
        for group in groups:
            inside = module == group or (group != "gprbot" and module.startswith(group + "."))
            if inside and (best is None or len(group) > len(best[1])):
                best = (rank, group)
    if best is None:
        raise AssertionError(f"{module} is in no layer: add it (or its package) to LAYERS in {__file__}")
    return best


def upward_imports(edges: list[Edge]) -> set[tuple[str, str]]:
    """(importer, imported) pairs whose target's group is not below the importer's."""
    bad = set()
    for e in edges:
        (rs, gs), (rt, gt) = group_of(e.source), group_of(e.target)
        if gs != gt and rt >= rs:
            bad.add((e.source, e.target))
    return bad


def cycles(edges: list[Edge]) -> list[list[str]]:
    """Strongly connected components (size > 1) of the group graph and of the module graph."""
    found: list[list[str]] = []
    runtime = [e for e in edges if not e.type_only]
    for key in (lambda m: group_of(m)[1], lambda m: m):
        graph: dict[str, set[str]] = {}
        for e in runtime:
            a, b = key(e.source), key(e.target)
            if a != b:
                graph.setdefault(a, set()).add(b)
        found += [c for c in _components(graph) if len(c) > 1]
    return found


def _components(graph: dict[str, set[str]]) -> list[list[str]]:
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def edges() -> list[Edge]:
    return list(import_edges(_modules()))


def test_every_module_has_a_layer() -> None:
    for module in _modules():
        group_of(module)


def test_no_upward_import(edges: list[Edge]) -> None:
    found = upward_imports(edges)
    new = sorted(found - KNOWN_UPWARD)
    gone = sorted(KNOWN_UPWARD - found)
    assert not new, "upward imports (move the code down or the import up; the layering is LAYERS):\n" + "\n".join(
        f"  {a} -> {b}  ({group_of(a)[1]} is layer {LAYERS[group_of(a)[0]][0]}, {group_of(b)[1]} is "
        f"{LAYERS[group_of(b)[0]][0]})" for a, b in new)
    assert not gone, f"fixed, so take them off KNOWN_UPWARD: {gone}"


def test_no_import_cycle(edges: list[Edge]) -> None:
    assert cycles(edges) == []


def test_sim_is_a_leaf_used_only_by_the_simulated_robot(edges: list[Edge]) -> None:
    users = sorted({(e.source, e.target) for e in edges
                    if group_of(e.target)[1] == "gprbot.sim" and not e.source.startswith(SIM_USERS)})
    assert users == [], f"only {SIM_USERS} may import the simulated world: {users}"
    uses = sorted({(e.source, e.target) for e in edges if group_of(e.source)[1] == "gprbot.sim"
                   and group_of(e.target)[1] != "gprbot.sim" and group_of(e.target)[0] > MODELS})
    assert uses == [], f"the simulated world imports only foundation, types and models: {uses}"


def test_the_checks_catch_what_they_are_for() -> None:
    low, high = "gprbot.messages", "gprbot.daemon"
    assert upward_imports([Edge(low, high, False, 1)]) == {(low, high)}
    assert upward_imports([Edge(high, low, False, 1)]) == set()
    loop = [Edge("gprbot.fusion.a", "gprbot.fusion.b", False, 1), Edge("gprbot.fusion.b", "gprbot.fusion.a", False, 1)]
    assert cycles(loop) == [["gprbot.fusion.a", "gprbot.fusion.b"]]
    assert cycles([*loop[:1], Edge("gprbot.fusion.b", "gprbot.fusion.a", True, 1)]) == []


def test_the_robot_runtime_loads_neither_the_simulated_world_nor_torch() -> None:
    code = ("import sys, gprbot.daemon, gprbot.robot.runtime; "
            "bad = sorted(m for m in sys.modules if m.startswith(('gprbot.sim.', 'gprbot.simulated', 'torch'))); "
            "print(bad); sys.exit(1 if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode == 0, f"the daemon imports at start: {done.stdout}{done.stderr}"


def test_no_wait_for_in_the_package() -> None:
    """asyncio.timeout, never asyncio.wait_for: on 3.11 wait_for can swallow a cancel (the e-stop path)."""
    calls = []
    for module, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and node.attr == "wait_for" and ast.unparse(node.value) == "asyncio":
                calls.append(f"{module}:{node.lineno}")
    assert calls == []
