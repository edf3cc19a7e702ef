"""Every pointer a reader may follow resolves: each ``docs/...`` path and each Python file of
``calib``, ``capture``, ``drivers``, ``service``, ``tests`` or ``bench`` named by its path in a ``*.py`` or ``*.md`` file (outside
``docs/decisions/``, which is history) exists, and each ``:mod:``, ``:func:``, ``:class:``, ``:data:``,
``:meth:`` or ``:attr:`` target in the code imports.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOPS = ("calib", "capture", "drivers", "service", "tests", "bench")
HISTORY = REPO / "docs" / "decisions"
# a path as written in prose or code: docs/<name>.md (or deeper), or <top>/.../<name>.py; not one
# after a colon, which is a file at a git revision (``git show f6d8965:calib/detect.py``)
PATH = re.compile(r"(?<![\w./:-])((?:docs/[\w./-]+?\.md)|(?:(?:" + "|".join(TOPS) + r")/[\w./-]+?\.py))(?![\w/-])")
ROLE = re.compile(r":(?:mod|func|class|data|meth|attr|exc):`~?([\w.]+)`")


def _files(suffixes: tuple[str, ...]) -> list[Path]:
    out = []
    for path in sorted(REPO.rglob("*")):
        rel = path.relative_to(REPO)
        if path.suffix not in suffixes or rel.parts[0].startswith(".") or rel.parts[0] in ("build", "dist"):
            continue
        if "egg-info" in rel.parts[0] or path.is_relative_to(HISTORY):
            continue
        out.append(path)
    return out


def _exists(name: str, here: Path) -> bool:
    """A named path exists from the repository's root, or (a docs/ link written relative) beside the file."""
    return (REPO / name).exists() or (here.parent / name).exists()


def test_named_paths_exist():
    missing = []
    for path in _files((".py", ".md")):
        for k, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            missing += [f"{path.relative_to(REPO)}:{k} names {name}" for name in PATH.findall(line)
                        if "*" not in name and not _exists(name, path)]
    assert not missing, "paths that do not exist (moved? renamed?): " + "; ".join(missing)


def _resolves(target: str) -> bool:
    """Import the longest importable prefix of ``target`` and getattr the rest."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


def _targets() -> list[tuple[str, str]]:
    out = []
    for path in _files((".py",)):
        if path.relative_to(REPO).parts[0] not in ("calib", "capture", "drivers", "service"):
            continue
        for k, line in enumerate(path.read_text().splitlines(), 1):
            out += [(f"{path.relative_to(REPO)}:{k}", t) for t in ROLE.findall(line) if t.startswith("wandcal.")]
    return out


@pytest.mark.parametrize("top", ["calib", "capture", "drivers", "service"])
def test_cross_references_import(top):
    bad = [f"{where} :...:`{target}`" for where, target in _targets() if where.startswith(top + "/")
           and not _resolves(target)]
    assert not bad, "cross-references that import nothing: " + "; ".join(bad)


def _faces() -> list[Path]:
    """The package faces that carry a table of their modules (rows ``| :mod:`...` | ... |``)."""
    faces = [p for top in ("calib", "capture", "drivers", "service") for p in sorted((REPO / top).rglob("__init__.py"))]
    return [p for p in faces if re.search(r"^\| :mod:", p.read_text(), re.M)]


@pytest.mark.parametrize("face", _faces(), ids=lambda p: str(p.parent.relative_to(REPO)))
def test_package_faces_list_every_module(face):
    """A face's table names each of its modules and sub-packages, so the folder reads as its contents."""
    package = "wandcal." + ".".join(face.parent.relative_to(REPO).parts)
    named = set(ROLE.findall(face.read_text()))
    members = [p.stem for p in face.parent.glob("*.py") if p.stem not in ("__init__", "__main__")]
    members += [p.parent.name for p in face.parent.glob("*/__init__.py")]
    missing = sorted(m for m in members if f"{package}.{m}" not in named)
    assert not missing, f"{face.relative_to(REPO)}'s table leaves out {', '.join(missing)}"
