"""The library's layers (README, "Layout"): no package imports from a higher layer, no import circle between
packages. Every ``import`` of every module under ``src/robocal`` is read with :mod:`ast` (imports inside
functions and under ``TYPE_CHECKING`` count: they are dependencies all the same).

A "package" is a folder of ``src/robocal`` or a top-level module (``robot.py``, ``io.py`` ...). ``import robocal``
and ``from robocal import name`` go through the lazy public API (``robocal/__init__.py``): they are resolved to
the module behind each name used, so the facade hides no dependency.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "robocal"

#: lowest first; a package may import its own layer and the layers below it
LAYERS: list[set[str]] = [
    # foundation: errors, settings, atomic files, MLflow, robot descriptions, the chain, error statistics; the version
    {
        "errors",
        "config",
        "io",
        "tracking",
        "robot",
        "robot_dh",
        "robot_files",
        "robot_keys",
        "pipeline",
        "kinematics",
        "metrics",
        "status",
        "numerics",
        "logged_signals",
        "parallel",
        "__version__",
    },
    # the data contract
    {"data"},
    # the fit's tools: the model, FitResult, identifiability, gross errors; the least-squares core, the optimizers
    {"identification", "optimizers"},
    # the geometric calibration (config, start, solve, screening, result and record, validation, calibrate); the
    # report helpers every capability uses
    {"calibration", "report"},
    # the capabilities: effect models, discovery, planning, compensation, the service, cell programs
    {"thermal", "compliance", "discovery", "plan", "compensation", "serve", "cell"},
    # end-to-end workflows over the capabilities (what the stages and commands call)
    {"workflows"},
    # the twin and the experiments run on it (closed loops drive the service with fitted models)
    {"sim"},
    # many robots over time; ISO 9283 characteristics (both run the twin and the service)
    {"fleet", "iso9283"},
    # the entry points: the public API facade, the CLI commands
    {"robocal", "commands", "cli", "exps"},
]

#: (importer package, imported package) -> why it is allowed for now. Each one is known and to be removed.
EXCEPTIONS: dict[tuple[str, str], str] = {}


#: (importer module, imported module) -> why; module-level circles known and to be removed
MODULE_EXCEPTIONS: dict[tuple[str, str], str] = {}


def _layer_of() -> dict[str, int]:
    out: dict[str, int] = {}
    for i, layer in enumerate(LAYERS):
        for p in layer:
            assert p not in out, f"{p} in two layers"
            out[p] = i
    return out


def _package(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "robocal":
        raise ValueError(module)
    return parts[1] if len(parts) > 1 else "robocal"


def _api() -> dict[str, str]:
    """The lazy facade's ``name -> module`` (parsed, not imported: this test imports no robocal code)."""
    tree = ast.parse((SRC / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.AnnAssign | ast.Assign) and isinstance(node.value, ast.Dict):
            keys = [k.value for k in node.value.keys if isinstance(k, ast.Constant)]
            vals = [v.value.split(":")[0] for v in node.value.values if isinstance(v, ast.Constant)]
            return {"__version__": "robocal.__version__", **dict(zip(keys, vals, strict=True))}
    raise AssertionError("robocal/__init__.py: no _API table")


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, api: dict[str, str]) -> set[str]:
    """The robocal modules ``path`` imports (facade names resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    mods: set[str] = set()
    bare_robocal = False
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "robocal":
                    bare_robocal = True
                elif a.name.startswith("robocal."):
                    mods.add(a.name)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import (the project uses absolute imports)"
            if node.module == "robocal":
                for a in node.names:
                    assert a.name in api, f"{path}: from robocal import {a.name}: not in the public API"
                    mods.add(api[a.name])
            elif node.module and node.module.startswith("robocal."):
                base = SRC.parent.joinpath(*node.module.split("."))
                for a in node.names:  # from robocal.pkg import submodule
                    sub = base / a.name
                    mods.add(
                        f"{node.module}.{a.name}" if sub.with_suffix(".py").is_file() or sub.is_dir() else node.module
                    )
    if bare_robocal:  # robocal.<name> attribute uses through the facade
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)):
                continue
            if node.value.id == "robocal" and node.attr in api:
                mods.add(api[node.attr])
    return mods


def _edges() -> dict[tuple[str, str], set[str]]:
    """(importer package, imported package) -> the importing modules; edges within a package left out."""
    api = _api()
    edges: dict[tuple[str, str], set[str]] = defaultdict(set)
    for path in sorted(SRC.rglob("*.py")):
        mod = _module_name(path)
        if mod == "robocal":
            continue  # the facade itself: its table is what the names above resolve through
        src = _package(mod)
        for target in _imports(path, api):
            dst = "__version__" if target == "robocal.__version__" else _package(target)
            if dst != src:
                edges[(src, dst)].add(mod)
    return edges


def test_every_package_has_a_layer():
    layer = _layer_of()
    packages = {p.stem for p in SRC.glob("*.py") if p.stem != "__init__"}
    packages |= {p.name for p in SRC.iterdir() if p.is_dir() and any(p.glob("*.py"))}
    missing = sorted(packages - set(layer))
    assert not missing, f"packages without a layer in tests/test_layers.py (and README's Layout): {missing}"


def test_no_import_from_a_lower_layer_to_a_higher_one():
    layer = _layer_of()
    bad = [
        f"{src} (layer {layer[src]}) imports {dst} (layer {layer[dst]}) in {', '.join(sorted(mods))}"
        for (src, dst), mods in sorted(_edges().items())
        if layer[dst] > layer[src] and (src, dst) not in EXCEPTIONS
    ]
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_the_exceptions_are_still_needed():
    edges = _edges()
    stale = [pair for pair in EXCEPTIONS if pair not in edges]
    assert not stale, f"exceptions no longer needed (remove them from EXCEPTIONS): {stale}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one package (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_circle_between_packages():
    graph: dict[str, set[str]] = defaultdict(set)
    for src, dst in _edges():
        if (src, dst) not in EXCEPTIONS:
            graph[src].add(dst)
    cycles = _cycles(graph)
    assert not cycles, f"import circles between packages: {cycles}"


def test_no_import_circle_between_modules():
    """Within a package too (the fleet's engine and registry imported each other through ``campaign_dir``)."""
    api = _api()
    modules = {_module_name(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = defaultdict(set)
    for mod, path in modules.items():
        for target in _imports(path, api):
            while target not in modules and "." in target:  # from robocal.x import some_function
                target = target.rsplit(".", 1)[0]
            if target != mod and (mod, target) not in MODULE_EXCEPTIONS:
                graph[mod].add(target)
    cycles = _cycles(graph)
    assert not cycles, f"import circles between modules: {cycles}"


def test_the_module_exceptions_are_still_needed():
    api = _api()
    stale = [(a, b) for a, b in MODULE_EXCEPTIONS if b not in _imports(SRC / (a.replace(".", "/")[8:] + ".py"), api)]
    assert not stale, f"module exceptions no longer needed (remove them from MODULE_EXCEPTIONS): {stale}"


def test_the_checker_sees_an_upward_import(tmp_path):
    """The parser finds imports inside functions and through the facade (so a clean run means something)."""
    f = tmp_path / "m.py"
    f.write_text(
        "import robocal\n\ndef g():\n    from robocal.workflows.geometric import x\n    return robocal.simulate\n"
    )
    assert _imports(f, _api()) == {"robocal.workflows.geometric", "robocal.sim.twin"}
