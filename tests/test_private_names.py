"""No private name crosses a package boundary: a name that starts with ``_`` is its module's business, so no module
of another package of ``src/robocal`` (a folder, or a top-level module such as ``robot.py``) imports it, and
neither do the stages, benchmarks and experiments. Shared helpers are public (``report.plots.styled``,
``sim.twin.rng_factory``, ``tracking.retry``, ``robot.SHIPPED_ROBOT_DIR``) or live where they are used.

Read with :mod:`ast`, like tests/test_layers.py: ``from robocal.x import _name`` and ``module._name`` where
``module`` was imported from another package (``from robocal.report import plots`` ... ``plots._STYLE``) both
count; dunder names do not. Tests may reach into a module's privates: they are not read here.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src" / "robocal"
OUTSIDE = ["stages", "benchmarks", "experiments"]


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _package(module: str) -> str:
    """``robocal.report.plots`` -> ``report``; ``robocal`` -> ``robocal``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _is_module(module: str) -> bool:
    path = REPO / "src" / module.replace(".", "/")
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def crossings(path: Path, here: str | None) -> list[str]:
    """The private names ``path`` takes from robocal packages other than ``here`` (None: every package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    modules: dict[str, str] = {}  # local name -> robocal module it is bound to
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "robocal":
            if node.level or _package(node.module) == here:
                continue
            for alias in node.names:
                if _private(alias.name):
                    found.append(f"line {node.lineno}: from {node.module} import {alias.name}")
                elif _is_module(f"{node.module}.{alias.name}"):
                    modules[alias.asname or alias.name] = f"{node.module}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("robocal.") and _package(alias.name) != here:
                    modules[alias.asname or alias.name] = alias.name
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr) and ast.unparse(node.value) in modules:
            found.append(f"line {node.lineno}: {modules[ast.unparse(node.value)]}.{node.attr}")
    return found


def test_no_private_name_is_imported_across_packages() -> None:
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).with_suffix("")
        here = rel.parts[0] if rel.parts[0] != "__init__" else "robocal"
        bad += [f"src/robocal/{path.relative_to(SRC)} {c}" for c in crossings(path, here)]
    for folder in OUTSIDE:
        for path in sorted((REPO / folder).rglob("*.py")):
            bad += [f"{path.relative_to(REPO)} {c}" for c in crossings(path, None)]
    assert not bad, "private names used outside their package (make them public, or move them):\n" + "\n".join(bad)


def test_the_check_sees_both_forms(tmp_path: Path) -> None:
    """The reader finds a private import and a private attribute of an imported module, and leaves its own
    package's privates alone."""
    f = tmp_path / "m.py"
    f.write_text(
        "from robocal.tracking import _x, ok\nfrom robocal.report import plots\nplots._STYLE\n"
        "from robocal.thermal.model import _own\n"
    )
    found = crossings(f, "thermal")
    assert found == ["line 1: from robocal.tracking import _x", "line 3: robocal.report.plots._STYLE"], found
