"""One idea, one definition (issue 32): the 3-D RMS of position errors is computed by :class:`robocal.metrics.
ErrorStats` only, and which parameters a setting holds fixed (shell patterns over the parameter names) and the
order parameters are kept in are resolved by :mod:`robocal.identification.identifiability` only, for calibrate,
plan and discovery alike; compensation has one entry point, ``correct``, and the correction beyond the calibration's
own one definition (:mod:`robocal.compensation.correct`); ``needs`` one meaning. Read with :mod:`ast` over
``src/robocal``.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.identification.identifiability import keep_order, resolve_fixed
from robocal.metrics import ErrorStats

SRC = Path(__file__).resolve().parents[1] / "src" / "robocal"
HOME_RMS = SRC / "metrics.py"
HOME_FIXED = SRC / "identification" / "identifiability.py"
HOME_CORRECT = SRC / "compensation" / "correct.py"


@functools.cache  # parsed once for every check
def _modules() -> list[tuple[Path, ast.Module]]:
    return [(p, ast.parse(p.read_text(encoding="utf-8"))) for p in sorted(SRC.rglob("*.py"))]


def _call(node: ast.AST, name: str) -> ast.Call | None:
    """``node`` when it is a call of ``name`` (``np.name`` or ``name``), else None."""
    if isinstance(node, ast.Call):
        f = node.func
        if (isinstance(f, ast.Attribute) and f.attr == name) or (isinstance(f, ast.Name) and f.id == name):
            return node
    return None


def _is_rms3d(node: ast.AST) -> bool:
    """``sqrt(mean(sum(x**2, axis=1)))`` (per-row squared norms) or ``sqrt(mean(x**2) * 3)`` (the same from flat
    xyz triples): a hand-coded 3-D RMS."""
    sqrt = _call(node, "sqrt")
    if sqrt is None or not sqrt.args:
        return False
    arg = sqrt.args[0]
    mean = _call(arg, "mean")
    if mean is not None and mean.args:
        inner = _call(mean.args[0], "sum")
        return inner is not None and any(k.arg == "axis" and ast.unparse(k.value) == "1" for k in inner.keywords)
    if isinstance(arg, ast.BinOp) and isinstance(arg.op, ast.Mult):
        sides = (arg.left, arg.right)
        return any(_call(s, "mean") for s in sides) and any(ast.unparse(s) == "3" for s in sides)
    return False


def test_the_3d_rms_is_computed_by_error_stats_only() -> None:
    found = [
        f"{p.relative_to(SRC)}:{n.lineno}: {ast.unparse(n)}"
        for p, tree in _modules()
        if p != HOME_RMS
        for n in ast.walk(tree)
        if _is_rms3d(n)
    ]
    assert not found, "3-D RMS computed by hand (use robocal.metrics.ErrorStats.of(errors).rms_mm):\n" + "\n".join(
        found
    )


def test_the_check_sees_a_hand_coded_rms() -> None:
    for code in ("np.sqrt(np.mean(np.sum(r**2, axis=1)))", "float(np.sqrt(np.mean(r**2) * 3))"):
        assert any(_is_rms3d(n) for n in ast.walk(ast.parse(code))), code
    assert not any(_is_rms3d(n) for n in ast.walk(ast.parse("np.sqrt(np.mean(e**2))")))  # a 1-D RMS


def test_fixed_parameters_are_resolved_in_one_place() -> None:
    """No other module defines a resolution of fixed patterns (``fnmatch`` over parameter names) or its own
    keep order."""
    found = []
    for p, tree in _modules():
        if p == HOME_FIXED:
            continue
        for n in ast.walk(tree):
            if isinstance(n, ast.FunctionDef) and ("fixed" in n.name or "candidate_order" in n.name):
                found.append(f"{p.relative_to(SRC)}:{n.lineno}: def {n.name}")
            if isinstance(n, ast.Attribute) and n.attr == "filter" and ast.unparse(n.value) == "fnmatch":
                found.append(f"{p.relative_to(SRC)}:{n.lineno}: fnmatch.filter")
    assert not found, "use identification.identifiability.ParameterSpec (resolve_fixed / keep_order):\n" + "\n".join(
        found
    )


def test_resolve_fixed_names_the_setting_and_the_pattern() -> None:
    names = ("base_tx", "theta1", "theta2", "a2")
    assert resolve_fixed(names, ("theta*", "a2"), "calibration.fixed") == {"theta1", "theta2", "a2"}
    assert resolve_fixed(names, (), "plan.fixed") == set()
    with pytest.raises(ConfigError, match=r"'plan\.fixed' setting names 'd\*', which matches no parameter"):
        resolve_fixed(names, ("theta1", "d*"), "plan.fixed")
    # the keep order the three share: frames, tools, then the joint-level parameters; fixed ones left out
    names = ("theta1", "base_tx", "tool_x", "a2")
    kinds = ("kinematic", "base", "tool", "kinematic")
    assert keep_order(kinds, names, {"a2"}) == [1, 2, 0]


def test_error_stats_rms_is_the_3d_rms() -> None:
    """What the replaced hand-coded lines computed, to the last bits that the files keep."""
    rng = np.random.default_rng(0)
    r = rng.normal(0.0, 0.05, (200, 3))
    by_hand = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    # the same sum in another order: equal to a few ulp, and so to the 6 decimals (mm) the files write
    assert ErrorStats.of(r).rms_mm == pytest.approx(by_hand, rel=1e-14)
    assert ErrorStats.of(r.ravel().reshape(-1, 3)).rms_mm == ErrorStats.of(r).rms_mm


def _defs(name: str) -> list[str]:
    """Where a module-level function ``name`` is defined (methods such as the service's ``correct`` op are not
    compensation entry points)."""
    return [
        f"{p.relative_to(SRC)}"
        for p, tree in _modules()
        for n in tree.body
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == name
    ]


def test_one_compensation_entry_point_and_one_beyond_own_correction() -> None:
    """``correct`` is defined once (compensation/correct.py); the old judges and the thermal copy of the
    beyond-own correction are gone; the own correction and what lies beyond it are computed in
    compensation/correct.py only (no other module calls ``beyond_own``, ``own_correction`` or ``bound_measures``,
    nor defines a function of that name)."""
    assert _defs("correct") == ["compensation/correct.py"]
    for gone in ("judge_compensation", "_beyond_own_correction", "_compensate_by_target"):
        assert _defs(gone) == [], gone
    names = ("beyond_own", "own_correction", "bound_measures")
    for name in names:
        assert _defs(name) == ["compensation/correct.py"], name
    found = []
    for p, tree in _modules():
        if p == HOME_CORRECT:
            continue
        for n in ast.walk(tree):
            call = next((c for c in (_call(n, name) for name in names) if c is not None), None)
            if call is not None:
                found.append(f"{p.relative_to(SRC)}:{n.lineno}: {ast.unparse(n)}")
    assert not found, "the beyond-own correction computed outside compensation/correct.py:\n" + "\n".join(found)


def test_needs_has_one_meaning() -> None:
    """``needs`` is what a joint-space effect needs among ``robocal.compensation.effects.SIGNALS`` (the protocol's
    property and its one module-level function); the request fields the discovered records read are
    ``request_fields``."""
    from robocal.compensation.discovered import DiscoveredEffects, request_fields

    assert _defs("needs") == ["compensation/effects.py"]
    rec = [{"key": "backlash:j2", "signal": "direction", "joint": 2, "coefficients": [1e-4]}]
    assert request_fields(rec) == {"dir"}
    assert DiscoveredEffects(tuple(rec), None).needs == frozenset({"direction"})
