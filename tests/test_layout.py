"""The layout rule of docs/architecture.md, read from the imports themselves.

Every module's imports (module level and inside functions) are parsed, not executed. The rules:
one ``wandcal`` namespace and none of the old top-level names; service -> capture -> drivers, with
calib underneath all of them and importing none; inside calib, a stage imports only its own
package and the stages below it; no circle between calib's files; and no folder of calib holds more
than a dozen modules.
"""

from __future__ import annotations

import ast
import tomllib
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "capture", "drivers", "service")
OLD_NAMES = set(PACKAGES)
# Which top-level package may import which (habit 1 of the style guide).
ALLOWED = {
    "calib": {"calib"},
    "drivers": {"drivers", "calib"},
    "capture": {"capture", "drivers", "calib"},
    "service": {"service", "capture", "drivers", "calib"},
}
# calib's stages, lowest first: a module imports its own group and lower ranks only, never a
# group of the same rank (detect, start and solve know nothing of one another).
CALIB_RANK = {
    "core": 0,
    "detect": 1, "start": 1, "solve": 1,
    "judge": 2,
    "run": 3,
    "sim": 4,
}
CORE = {"errors", "rig", "geometry", "observations", "triangulate", "wandlayout"}
MAX_MODULES_PER_FOLDER = 12


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return "wandcal." + ".".join(parts)


def _sources(top: str | None = None) -> list[Path]:
    tops = [top] if top else [*PACKAGES, "tests", "bench"]
    return sorted(p for t in tops for p in (REPO / t).rglob("*.py"))


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every absolute import in ``path``; ``from a import b`` gives ``a.b``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def _calib_group(name: str) -> str:
    """The stage of a ``wandcal.calib...`` module or of a name imported from one."""
    parts = name.split(".")[2:]
    if not parts or parts[0] in CORE or parts[0] in ("errors", "CalibrationError", "Camera", "Rig"):
        return "core"
    if parts[0] in CALIB_RANK:
        return parts[0]
    return "core"  # names the package re-exports from its core (wandcal.calib.Rig)


def _resolve(name: str, modules: set[str]) -> str | None:
    """The module a dotted import name lands in (``a.b.func`` -> ``a.b``)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def test_one_namespace_and_no_old_names():
    bad = [f"{p.relative_to(REPO)}:{line} imports {name}" for p in _sources() for line, name in _imports(p)
           if name.split(".")[0] in OLD_NAMES]
    assert not bad, "import through wandcal.*: " + "; ".join(bad)
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    declared = set(config["packages"])
    found = {_module_name(p) for top in PACKAGES for p in (REPO / top).rglob("__init__.py")}
    assert declared == found, f"pyproject.toml's packages differ from the folders: {declared ^ found}"
    assert all(name.startswith("wandcal.") for name in declared)
    assert config["package-dir"] == {f"wandcal.{top}": top for top in PACKAGES}


@pytest.mark.parametrize("top", PACKAGES)
def test_packages_import_one_way(top):
    bad = []
    for path in _sources(top):
        for line, name in _imports(path):
            parts = name.split(".")
            if parts[0] == "wandcal" and len(parts) > 1 and parts[1] not in ALLOWED[top]:
                bad.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    assert not bad, f"{top} may import only {sorted(ALLOWED[top])}: " + "; ".join(bad)


def _calib_graph() -> dict[str, set[str]]:
    paths = _sources("calib")
    modules = {_module_name(p) for p in paths}
    graph: dict[str, set[str]] = defaultdict(set)
    for path in paths:
        me = _module_name(path)
        for _, name in _imports(path):
            target = _resolve(name, modules) if name.startswith("wandcal.calib") else None
            if target and target not in (me, "wandcal.calib"):
                graph[me].add(target)
    return graph


def test_calib_stages_import_downwards():
    bad = []
    for me, targets in _calib_graph().items():
        mine = _calib_group(me)
        for target in targets:
            theirs = _calib_group(target)
            if theirs != mine and CALIB_RANK[theirs] >= CALIB_RANK[mine]:
                bad.append(f"{me} ({mine}) imports {target} ({theirs})")
    assert not bad, "docs/architecture.md's rule: " + "; ".join(sorted(bad))


def test_no_import_circle_in_calib():
    graph = _calib_graph()
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> list[str] | None:
        if node in path:
            return [*path[path.index(node):], node]
        if node in done:
            return None
        for nxt in graph.get(node, ()):
            if not nxt.startswith(node + "."):  # a package importing its own modules is no circle
                cycle = visit(nxt, [*path, node])
                if cycle:
                    return cycle
        done.add(node)
        return None

    for start in sorted(graph):
        cycle = visit(start, [])
        assert cycle is None, " -> ".join(cycle)


def test_calib_folders_stay_small():
    for folder in [REPO / "calib", *(p.parent for p in (REPO / "calib").rglob("*/__init__.py"))]:
        modules = [p for p in folder.glob("*.py") if p.name != "__init__.py"]
        assert len(modules) <= MAX_MODULES_PER_FOLDER, f"{folder.relative_to(REPO)} holds {len(modules)} modules"
